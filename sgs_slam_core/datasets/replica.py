"""Replica sequences in the NICE-SLAM and the SGS-SLAM layouts.

* NICE-SLAM: ``results/frame*.jpg``, ``results/depth*.png``, ``traj.txt``;
* SGS-SLAM: ``frames/frame*``, ``depths/depth*.png``, ``semantic_ids/semantic_id*.png``,
  ``semantic_colors/semantic_color*.png``, ``traj.txt``.

``traj.txt`` has one camera-to-world matrix per frame (16 numbers, row-major). Depth PNGs hold
metres x 6553.5. An optional ``camera.yaml`` overrides the default camera (1200x680, fx = fy = 600,
cx = 599.5, cy = 339.5). Class colours come from ``labels.yaml`` (a label table) when present, else
from the dataset's own ``semantic_colors`` images, else from the deterministic palette.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from sgs_slam_core.datasets.base import (
    DatasetOptions,
    FrameRecord,
    RecordDataset,
    read_color,
    read_label_png,
    rigid_or_none,
)
from sgs_slam_core.datasets.camera_file import read_camera_file
from sgs_slam_core.errors import DatasetError
from sgs_slam_core.fileio import read_text, read_yaml
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.labels import LabelClass, LabelError, LabelTable

__all__ = ["REPLICA_DEPTH_SCALE", "REPLICA_INTRINSICS", "ReplicaDataset", "read_trajectory_matrices"]

REPLICA_INTRINSICS = Intrinsics(600.0, 600.0, 599.5, 339.5, 1200, 680)
REPLICA_DEPTH_SCALE = 6553.5
FRAME_RATE_HZ = 30.0
_PALETTE_SCAN_FRAMES = 50


def _numbered(folder: Path, prefix: str, suffixes: tuple[str, ...]) -> list[Path]:
    """Files ``<prefix><number><suffix>`` sorted by number."""
    pattern = re.compile(rf"^{re.escape(prefix)}(\d+)$")
    found = []
    for path in folder.iterdir() if folder.is_dir() else ():
        match = pattern.match(path.stem)
        if match and path.suffix.lower() in suffixes:
            found.append((int(match.group(1)), path))
    return [p for _, p in sorted(found)]


def read_trajectory_matrices(path: Path) -> list[np.ndarray]:
    """4x4 matrices from a file with 16 numbers per line (row-major); NaN/inf rows stay (no ground truth)."""
    if not path.is_file():
        raise DatasetError(f"missing trajectory file {path}")
    poses = []
    for lineno, line in enumerate(read_text(path, "trajectory file").splitlines(), 1):
        if not line.strip():
            continue
        try:
            values = np.array([float(v) for v in line.split()], dtype=np.float64)
        except ValueError as err:
            raise DatasetError(f"{path}:{lineno}: not a number ({err})") from err
        if values.size != 16:
            raise DatasetError(f"{path}:{lineno}: expected 16 numbers, got {values.size}")
        poses.append(values.reshape(4, 4))
    return poses


def _table_from_color_images(ids: list[Path], colors: list[Path]) -> LabelTable:
    """Id -> colour pairs sampled from up to 50 evenly spaced frames of the dataset's own images."""
    picks = np.unique(np.linspace(0, len(ids) - 1, min(len(ids), _PALETTE_SCAN_FRAMES)).round().astype(int))
    seen: dict[int, tuple[int, int, int]] = {}
    for i in picks:
        lab = read_label_png(ids[i]).reshape(-1)
        col = read_color(colors[i]).reshape(-1, 3)
        if lab.shape[0] != col.shape[0]:
            raise DatasetError(f"{colors[i]} and {ids[i]} differ in size")
        uniq, first = np.unique(lab, return_index=True)
        for class_id, idx in zip(uniq.tolist(), first.tolist(), strict=True):
            seen.setdefault(class_id, tuple(int(v) for v in col[idx]))  # type: ignore[arg-type]
    return LabelTable((LabelClass(i, f"class_{i}", c) for i, c in seen.items() if i != 0), name="replica")


class ReplicaDataset(RecordDataset):
    """A Replica scene folder in either layout (detected from the folder contents)."""

    name = "replica"

    def __init__(self, root: str | Path, options: DatasetOptions | None = None) -> None:
        root = Path(root)
        self.root = root
        cam = read_camera_file(root / "camera.yaml") if (root / "camera.yaml").is_file() else None
        native = cam.intrinsics if cam else REPLICA_INTRINSICS
        depth_scale = cam.depth_scale if cam and cam.depth_scale else REPLICA_DEPTH_SCALE
        labels: list[Path] = []
        if (root / "frames").is_dir():
            self.layout = "sgs-slam"
            colors = _numbered(root / "frames", "frame", (".jpg", ".jpeg", ".png"))
            depths = _numbered(root / "depths", "depth", (".png",))
            labels = _numbered(root / "semantic_ids", "semantic_id", (".png",))
            sem_colors = _numbered(root / "semantic_colors", "semantic_color", (".png", ".jpg"))
        elif (root / "results").is_dir():
            self.layout = "nice-slam"
            colors = _numbered(root / "results", "frame", (".jpg", ".jpeg", ".png"))
            depths = _numbered(root / "results", "depth", (".png",))
            sem_colors = []
        else:
            raise DatasetError(f"{root} is not a Replica folder (no frames/ or results/)")
        if not colors:
            raise DatasetError(f"{root}: no colour frames found")
        if len(depths) != len(colors) or (labels and len(labels) != len(colors)):
            raise DatasetError(
                f"{root}: {len(colors)} colour, {len(depths)} depth and {len(labels)} label images; they must match"
            )
        poses = read_trajectory_matrices(root / "traj.txt")
        if len(poses) != len(colors):
            raise DatasetError(f"{root / 'traj.txt'} has {len(poses)} poses for {len(colors)} frames")
        traj = root / "traj.txt"
        records = [
            FrameRecord(
                color=c,
                depth=d,
                stamp_ns=round(i * 1e9 / FRAME_RATE_HZ),
                labels=labels[i] if labels else None,
                gt_c2w=rigid_or_none(p, f"{traj}: pose {i + 1}"),
            )
            for i, (c, d, p) in enumerate(zip(colors, depths, poses, strict=True))
        ]
        super().__init__(
            records, native, depth_scale, self._label_table(root, labels, sem_colors), options or DatasetOptions()
        )

    @staticmethod
    def _label_table(root: Path, labels: list[Path], sem_colors: list[Path]) -> LabelTable:
        if (root / "labels.yaml").is_file():
            try:
                return LabelTable.from_dict(read_yaml(root / "labels.yaml", "label table"))
            except LabelError as err:
                raise DatasetError(f"bad label table {root / 'labels.yaml'}: {err}") from err
        if labels and len(sem_colors) == len(labels):
            return _table_from_color_images(labels, sem_colors)
        return LabelTable(name="replica")
