"""Trajectory files in TUM format and a trajectory plot (PNG, drawn with OpenCV)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import torch

from sgs_slam_core.errors import DatasetError, ShapeError
from sgs_slam_core.fileio import read_text, write_image, write_text
from sgs_slam_core.geometry.se3 import quat_to_rotmat, rotmat_to_quat

__all__ = ["plot_trajectories", "read_tum_trajectory", "write_tum_trajectory"]


def write_tum_trajectory(path: str | Path, stamps_ns: list[int], c2w: np.ndarray) -> None:
    """One line per pose: ``stamp_s tx ty tz qx qy qz qw`` (camera-to-world)."""
    c2w = np.asarray(c2w, dtype=np.float64)
    if c2w.ndim != 3 or c2w.shape[1:] != (4, 4) or len(stamps_ns) != len(c2w):
        raise ShapeError(f"need N stamps and [N, 4, 4] poses, got {len(stamps_ns)} and {c2w.shape}")
    quats = rotmat_to_quat(torch.from_numpy(c2w[:, :3, :3])).numpy()  # wxyz
    lines = ["# timestamp tx ty tz qx qy qz qw"]
    for stamp, pose, q in zip(stamps_ns, c2w, quats, strict=True):
        t = pose[:3, 3]
        lines.append(
            f"{stamp // 1_000_000_000}.{stamp % 1_000_000_000:09d} "
            f"{t[0]:.9f} {t[1]:.9f} {t[2]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f} {q[0]:.9f}"
        )
    write_text(path, "\n".join(lines) + "\n")  # atomic


def read_tum_trajectory(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """``(stamps_ns [N] int64, c2w [N, 4, 4])`` from a TUM trajectory file."""
    path = Path(path)
    text = read_text(path, "trajectory")  # DatasetError when missing, unreadable or binary
    stamps, rows = [], []
    for lineno, line in enumerate(text.splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        parts = line.split()
        if len(parts) != 8:
            raise DatasetError(f"{path}:{lineno}: expected 8 columns, got {len(parts)}")
        sec, _, frac = parts[0].partition(".")
        try:
            stamps.append(int(sec) * 1_000_000_000 + int((frac + "000000000")[:9]))
            rows.append([float(v) for v in parts[1:]])
        except ValueError as err:
            raise DatasetError(f"{path}:{lineno}: {err}") from err
    data = np.array(rows, dtype=np.float64).reshape(-1, 7)
    poses = np.tile(np.eye(4), (len(data), 1, 1))
    wxyz = np.concatenate([data[:, 6:7], data[:, 3:6]], axis=1)
    poses[:, :3, :3] = quat_to_rotmat(torch.from_numpy(wxyz)).numpy()
    poses[:, :3, 3] = data[:, :3]
    return np.array(stamps, dtype=np.int64), poses


def _panel(est: np.ndarray, gt: np.ndarray | None, axes: np.ndarray, title: str) -> np.ndarray:
    size, margin = 420, 40
    img = np.full((size, size, 3), 255, np.uint8)
    pts = [p @ axes.T for p in (est, gt) if p is not None]  # axes: [2, 3] projection rows
    allp = np.concatenate(pts)
    lo, hi = allp.min(0), allp.max(0)
    span = max(float((hi - lo).max()), 1e-6)
    centre = (lo + hi) / 2

    def px(p: np.ndarray) -> np.ndarray:
        q = (p - centre) / span * (size - 2 * margin) + size / 2
        return np.stack([q[:, 0], size - q[:, 1]], 1).round().astype(np.int32)

    cv2.rectangle(img, (margin // 2, margin // 2), (size - margin // 2, size - margin // 2), (220, 220, 220), 1)
    if gt is not None:
        for a, b in zip(px(pts[0]), px(pts[1]), strict=True):
            cv2.line(img, tuple(int(v) for v in a), tuple(int(v) for v in b), (120, 120, 255), 1)
        cv2.polylines(img, [px(pts[1])], False, (40, 40, 40), 2, cv2.LINE_AA)
    cv2.polylines(img, [px(pts[0])], False, (200, 110, 0), 2, cv2.LINE_AA)
    cv2.putText(img, title, (margin // 2, margin // 2 - 6), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, f"scale: {span:.2f} m across", (margin // 2 + 4, size - margin // 2 - 6),
                cv2.FONT_HERSHEY_SIMPLEX, 0.4, (90, 90, 90), 1, cv2.LINE_AA)  # fmt: skip
    return img


def plot_trajectories(path: str | Path, est_c2w: np.ndarray, gt_c2w: np.ndarray | None = None, title: str = "") -> None:
    """PNG with two views of the camera centres along the trajectory's principal axes.

    "Top" shows the plane of the two directions of largest spread, "side" the first against the
    least-spread direction, whatever the world frame's convention. The estimate is drawn in blue,
    the (aligned) ground truth in black and per-frame errors as thin red segments.
    """
    est = np.asarray(est_c2w)[:, :3, 3]
    gt = np.asarray(gt_c2w)[:, :3, 3] if gt_c2w is not None else None
    ref = gt if gt is not None else est
    _, _, vt = np.linalg.svd(ref - ref.mean(0), full_matrices=True)  # rows: principal directions
    top = _panel(est, gt, vt[[0, 1]], "top view (principal axes 1 and 2)")
    side = _panel(est, gt, vt[[0, 2]], "side view (principal axes 1 and 3)")
    header = np.full((34, top.shape[1] * 2, 3), 255, np.uint8)
    legend = (
        f"{title}   blue: estimate   black: ground truth   red: error"
        if gt is not None
        else f"{title}   blue: estimate"
    )
    cv2.putText(header, legend, (10, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    write_image(path, np.concatenate([header, np.concatenate([top, side], 1)], 0))  # atomic
