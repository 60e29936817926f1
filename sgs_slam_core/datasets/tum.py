"""TUM RGB-D benchmark folders (``rgb.txt``, ``depth.txt``, ``groundtruth.txt``).

Colour and depth are associated by nearest time stamp within 20 ms, one-to-one (as TUM's
``associate.py``); ground truth (100 Hz motion capture, pose of the colour optical centre) is
interpolated at the colour stamp, linearly for the position and by slerp for the rotation. Frames
outside the ground-truth span, or inside a gap of the motion capture, get none.
"""

from __future__ import annotations

import logging
import math
import re
from pathlib import Path

import numpy as np

from sgs_slam_core.datasets.base import DatasetOptions, FrameRecord, RecordDataset
from sgs_slam_core.datasets.camera_file import read_camera_file
from sgs_slam_core.errors import DatasetError
from sgs_slam_core.fileio import read_text
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.geometry.se3 import quat_xyzw_to_matrix
from sgs_slam_core.labels import LabelTable

__all__ = ["TUM_INTRINSICS", "TumDataset", "associate", "interpolate_poses", "read_ground_truth", "read_stamped_list"]

log = logging.getLogger(__name__)

# Per-sequence-family calibration (TUM's published ROS-default-free values), 640x480.
TUM_INTRINSICS = {
    "fr1": Intrinsics(517.3, 516.5, 318.6, 255.3, 640, 480),
    "fr2": Intrinsics(520.9, 521.0, 325.1, 249.7, 640, 480),
    "fr3": Intrinsics(535.4, 539.2, 320.1, 247.6, 640, 480),
}
TUM_DEPTH_SCALE = 5000.0
MAX_ASSOCIATION_S = 0.02
MAX_GT_GAP_S = 0.1


def _rows(path: Path, columns: int) -> list[tuple[int, float, list[str]]]:
    """``(line number, stamp s, other columns)`` of every data line of a TUM text file."""
    if not path.is_file():
        raise DatasetError(f"missing TUM file {path}")
    rows = []
    for lineno, raw in enumerate(read_text(path, "TUM list").splitlines(), 1):
        text = raw.strip()
        if not text or text.startswith("#"):
            continue
        parts = text.replace(",", " ").split()
        if len(parts) != columns + 1:
            raise DatasetError(f"{path}:{lineno}: expected {columns + 1} columns, got {len(parts)}")
        rows.append((lineno, _number(parts[0], path, lineno, "time stamp"), parts[1:]))
    return rows


def _number(text: str, path: Path, lineno: int, what: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise DatasetError(f"{path}:{lineno}: {what} {text!r} is not a finite number")
    return value


def read_stamped_list(path: Path, columns: int) -> tuple[np.ndarray, list[list[str]]]:
    """Rows of a TUM text file: ``(stamps [N] float64 s, the other columns as strings)``.

    The file is UTF-8 or ASCII; other bytes (a Latin-1 file name) are kept as surrogates, which name
    the same file on disk. A binary file, a wrong column count or a stamp that is not a finite
    number raises :class:`DatasetError` naming the file and line.
    """
    rows = _rows(path, columns)
    return np.array([t for _, t, _ in rows], dtype=np.float64), [rest for _, _, rest in rows]


def read_ground_truth(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """``groundtruth.txt`` as ``(stamps [M] s, poses [M, 7] tx ty tz qx qy qz qw)``, sorted by stamp.

    A value that is not a finite number, or a zero quaternion, raises :class:`DatasetError` naming
    the line and the field.
    """
    fields = ("tx", "ty", "tz", "qx", "qy", "qz", "qw")
    stamps, values = [], []
    for lineno, stamp, rest in _rows(path, 7):
        row = [_number(v, path, lineno, name) for v, name in zip(rest, fields, strict=True)]
        if math.hypot(*row[3:]) < 1e-6:
            raise DatasetError(f"{path}:{lineno}: quaternion (qx qy qz qw) is zero, not a rotation")
        stamps.append(stamp)
        values.append(row)
    t, poses = np.array(stamps, dtype=np.float64), np.array(values, dtype=np.float64).reshape(-1, 7)
    order = np.argsort(t, kind="stable")
    return t[order], poses[order]


def associate(a: np.ndarray, b: np.ndarray, max_dt: float = MAX_ASSOCIATION_S) -> list[tuple[int, int]]:
    """One-to-one pairs (i, j) with |a_i - b_j| < max_dt, closest pairs first; sorted by i."""
    if len(a) == 0 or len(b) == 0:
        return []
    order = np.argsort(b)
    b_sorted = b[order]
    pos = np.searchsorted(b_sorted, a)
    candidates = []
    for i, p in enumerate(pos):
        for q in (p - 1, p, p + 1):
            if 0 <= q < len(b_sorted):
                dt = abs(a[i] - b_sorted[q])
                if dt < max_dt:
                    candidates.append((dt, i, int(order[q])))
    candidates.sort()
    used_a, used_b, pairs = set(), set(), []
    for _, i, j in candidates:
        if i not in used_a and j not in used_b:
            used_a.add(i)
            used_b.add(j)
            pairs.append((i, j))
    return sorted(pairs)


def _slerp(q0: np.ndarray, q1: np.ndarray, s: float) -> np.ndarray:
    q0, q1 = q0 / np.linalg.norm(q0), q1 / np.linalg.norm(q1)
    dot = float(np.dot(q0, q1))
    if dot < 0:
        q1, dot = -q1, -dot
    if dot > 0.9995:
        q = q0 + s * (q1 - q0)
        return q / np.linalg.norm(q)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    return (np.sin((1 - s) * theta) * q0 + np.sin(s * theta) * q1) / np.sin(theta)


def interpolate_poses(
    gt_stamps: np.ndarray,  # [M] s, increasing
    gt: np.ndarray,  # [M, 7] tx ty tz qx qy qz qw
    query: np.ndarray,  # [N] s
    max_gap: float = MAX_GT_GAP_S,
) -> list[np.ndarray | None]:
    """c2w [4, 4] at each query stamp, or None outside the span or across a gap > ``max_gap``."""
    out: list[np.ndarray | None] = []
    for t in query:
        j = int(np.searchsorted(gt_stamps, t))
        if j < len(gt_stamps) and gt_stamps[j] == t:
            lo = hi = j
        elif j == 0 or j == len(gt_stamps):
            out.append(None)
            continue
        else:
            lo, hi = j - 1, j
        if gt_stamps[hi] - gt_stamps[lo] > max_gap:
            out.append(None)
            continue
        s = 0.0 if hi == lo else (t - gt_stamps[lo]) / (gt_stamps[hi] - gt_stamps[lo])
        pose = np.eye(4)
        pose[:3, 3] = (1 - s) * gt[lo, :3] + s * gt[hi, :3]
        pose[:3, :3] = quat_xyzw_to_matrix(*_slerp(gt[lo, 3:], gt[hi, 3:], s))
        out.append(pose)
    return out


def _sequence_intrinsics(root: Path) -> Intrinsics:
    match = re.search(r"(?:freiburg|fr)([123])", root.resolve().name.lower())
    if match:
        return TUM_INTRINSICS[f"fr{match.group(1)}"]
    log.warning("%s: cannot tell fr1/fr2/fr3 from the folder name; using fr1 intrinsics (add camera.yaml)", root)
    return TUM_INTRINSICS["fr1"]


class TumDataset(RecordDataset):
    """A TUM RGB-D sequence folder; ``camera.yaml`` beside ``rgb.txt`` overrides the calibration."""

    name = "tum"

    def __init__(self, root: str | Path, options: DatasetOptions | None = None) -> None:
        root = Path(root)
        self.root = root
        cam = read_camera_file(root / "camera.yaml") if (root / "camera.yaml").is_file() else None
        native = cam.intrinsics if cam else _sequence_intrinsics(root)
        depth_scale = cam.depth_scale if cam and cam.depth_scale else TUM_DEPTH_SCALE
        rgb_t, rgb_f = read_stamped_list(root / "rgb.txt", 1)
        depth_t, depth_f = read_stamped_list(root / "depth.txt", 1)
        pairs = associate(rgb_t, depth_t)
        unpaired = len(rgb_t) - len(pairs)
        # what the folder lists but the dataset leaves out, and why (the bag converter reports it)
        self.left_out = {f"colour images without a depth image within {MAX_ASSOCIATION_S * 1e3:.0f} ms": unpaired}
        if not pairs:
            raise DatasetError(f"{root}: no colour/depth pairs within {MAX_ASSOCIATION_S * 1e3:.0f} ms")
        poses: list[np.ndarray | None] = [None] * len(pairs)
        gt_file = root / "groundtruth.txt"
        if gt_file.is_file():
            gt_t, gt = read_ground_truth(gt_file)
            poses = interpolate_poses(gt_t, gt, rgb_t[[i for i, _ in pairs]])
        records = [
            FrameRecord(
                color=root / rgb_f[i][0],
                depth=root / depth_f[j][0],
                stamp_ns=round(rgb_t[i] * 1e9),
                gt_c2w=pose,
            )
            for (i, j), pose in zip(pairs, poses, strict=True)
        ]
        super().__init__(records, native, depth_scale, LabelTable(name="none"), options or DatasetOptions())
