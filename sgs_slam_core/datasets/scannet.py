"""ScanNet scenes exported from ``.sens`` (``color/``, ``depth/``, ``pose/``, ``intrinsic/``, ``label-filt/``).

Colour (1296x968) and labels are registered to the depth resolution (640x480): colour by area
averaging, labels nearest-neighbour, and the colour intrinsics are rescaled (as SplaTAM/SGS-SLAM).
Raw ScanNet label ids (16-bit, often above 255) are mapped to NYU40 through
``scannetv2-labels.combined.tsv`` (given by path, or found in the scene folder or its parent);
unknown ids become 0. Frames whose pose is not finite are skipped and counted in ``skipped``.
"""

from __future__ import annotations

import csv
import io
import logging
from pathlib import Path

import numpy as np

from sgs_slam_core.datasets.base import (
    DatasetOptions,
    FrameRecord,
    RecordDataset,
    read_color,
    read_depth_png,
    read_label_png,
    rigid_or_none,
)
from sgs_slam_core.errors import DatasetError
from sgs_slam_core.fileio import read_text
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.labels import LabelTable
from sgs_slam_core.validate import as_int

__all__ = ["ScanNetDataset", "read_label_mapping"]

log = logging.getLogger(__name__)

SCANNET_DEPTH_SCALE = 1000.0
FRAME_RATE_HZ = 30.0
TSV_NAME = "scannetv2-labels.combined.tsv"
MAX_RAW_ID = 65535  # raw label images are 16-bit


def read_label_mapping(path: Path) -> np.ndarray:  # [max_raw_id + 1] int32 raw id -> NYU40 id
    """Lookup table raw ScanNet id -> NYU40 id from the benchmark's TSV.

    Raw ids index 16-bit label images, so an id outside 0..65535 is an error (it would also size
    the table); NYU40 ids outside 0..40 map to 0 (unlabelled).
    """
    text = read_text(path, "label mapping")
    try:
        rows = list(csv.DictReader(io.StringIO(text, newline=""), delimiter="\t"))
    except csv.Error as err:
        raise DatasetError(f"label mapping {path} is not a TSV file: {err}") from err
    if not rows or "id" not in rows[0] or "nyu40id" not in rows[0]:
        raise DatasetError(f"label mapping {path} needs 'id' and 'nyu40id' columns")
    pairs = []
    for lineno, row in enumerate(rows, 2):
        raw = as_int(row["id"], f"{path}:{lineno}: id", DatasetError, 0, MAX_RAW_ID)
        nyu = as_int(row["nyu40id"] or 0, f"{path}:{lineno}: nyu40id", DatasetError)
        pairs.append((raw, nyu))
    lut = np.zeros(max(i for i, _ in pairs) + 1, dtype=np.int32)
    for raw, nyu in pairs:
        lut[raw] = nyu if 0 <= nyu <= 40 else 0
    return lut


def _read_matrix(path: Path) -> np.ndarray:  # [4, 4]
    text = read_text(path, "matrix file", max_bytes=1 << 16)
    try:
        rows = [[float(v) for v in line.split()] for line in text.splitlines() if line.strip()]
    except ValueError as err:
        raise DatasetError(f"matrix file {path} holds something that is not a number ({err})") from err
    if len(rows) != 4 or any(len(r) != 4 for r in rows):
        raise DatasetError(f"{path} must hold a 4x4 matrix, got rows of {[len(r) for r in rows]} numbers")
    return np.array(rows, dtype=np.float64)


def _find_tsv(root: Path, given: Path | None) -> Path | None:
    if given is not None:
        if not given.is_file():
            raise DatasetError(f"label mapping {given} not found")
        return given
    for folder in (root, root.parent):
        if (folder / TSV_NAME).is_file():
            return folder / TSV_NAME
    return None


class ScanNetDataset(RecordDataset):
    """An exported ScanNet scene."""

    name = "scannet"

    def __init__(self, root: str | Path, options: DatasetOptions | None = None, label_tsv: Path | None = None) -> None:
        root = Path(root)
        self.root = root
        for sub in ("color", "depth", "pose", "intrinsic"):
            if not (root / sub).is_dir():
                raise DatasetError(f"{root} is not an exported ScanNet scene: missing {sub}/")
        k_color = _read_matrix(root / "intrinsic" / "intrinsic_color.txt")
        stems = sorted((p.stem for p in (root / "color").glob("*.jpg")), key=lambda s: (len(s), s))
        if not stems:
            raise DatasetError(f"{root / 'color'}: no .jpg frames")
        first_depth = read_depth_png(root / "depth" / f"{stems[0]}.png", SCANNET_DEPTH_SCALE)
        first_color = read_color(root / "color" / f"{stems[0]}.jpg")
        color_k = Intrinsics.from_matrix(k_color, first_color.shape[1], first_color.shape[0])
        native = color_k.resized(first_depth.shape[1], first_depth.shape[0])
        tsv = _find_tsv(root, label_tsv)
        self._lut = read_label_mapping(tsv) if tsv else None
        has_labels = (root / "label-filt").is_dir()
        if has_labels and self._lut is None:
            raise DatasetError(f"{root}: label-filt/ present but no {TSV_NAME} beside the scene; pass its path")
        records, self.skipped = [], 0
        for i, stem in enumerate(stems):
            pose_file = root / "pose" / f"{stem}.txt"
            pose = rigid_or_none(_read_matrix(pose_file), str(pose_file))
            if pose is None:  # ScanNet marks frames without a pose with -inf
                self.skipped += 1
                continue
            records.append(
                FrameRecord(
                    color=root / "color" / f"{stem}.jpg",
                    depth=root / "depth" / f"{stem}.png",
                    stamp_ns=round(i * 1e9 / FRAME_RATE_HZ),
                    labels=root / "label-filt" / f"{stem}.png" if has_labels else None,
                    gt_c2w=pose,
                )
            )
        self.left_out = {"frames with non-finite poses": self.skipped}  # reported by the bag converter
        if self.skipped:
            log.info("%s: skipped %d frames with non-finite poses", root, self.skipped)
        super().__init__(records, native, SCANNET_DEPTH_SCALE, LabelTable.nyu40(), options or DatasetOptions())

    def decode(self, rec: FrameRecord) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Colour, depth and NYU40 labels; colour and labels are resized later to the depth size."""
        rgb = read_color(rec.color)
        depth = read_depth_png(rec.depth, SCANNET_DEPTH_SCALE)
        labels = None
        if rec.labels is not None:
            raw = read_label_png(rec.labels)
            lut = self._lut
            assert lut is not None
            labels = np.where(raw < len(lut), lut[np.minimum(raw, len(lut) - 1)], 0).astype(np.int32)
        h, w = self._native.shape
        if depth.shape != (h, w):
            raise DatasetError(f"depth image {rec.depth} is {depth.shape[1]}x{depth.shape[0]}, expected {w}x{h}")
        return rgb, depth, labels
