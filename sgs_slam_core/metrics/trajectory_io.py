"""Trajectory files in TUM format (plots: :func:`sgs_slam_core.viz.plot_trajectory`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from sgs_slam_core.errors import DatasetError, ShapeError
from sgs_slam_core.fileio import read_text, write_text
from sgs_slam_core.geometry.se3 import quat_to_rotmat, rotmat_to_quat

__all__ = ["read_tum_trajectory", "write_tum_trajectory"]


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
        if not np.isfinite(rows[-1]).all():
            raise DatasetError(f"{path}:{lineno}: a value is not finite")
        if np.linalg.norm(rows[-1][3:]) < 1e-9:
            raise DatasetError(f"{path}:{lineno}: quaternion (qx qy qz qw) is zero")
    data = np.array(rows, dtype=np.float64).reshape(-1, 7)
    poses = np.tile(np.eye(4), (len(data), 1, 1))
    wxyz = np.concatenate([data[:, 6:7], data[:, 3:6]], axis=1)
    poses[:, :3, :3] = quat_to_rotmat(torch.from_numpy(wxyz)).numpy()
    poses[:, :3, 3] = data[:, :3]
    return np.array(stamps, dtype=np.int64), poses
