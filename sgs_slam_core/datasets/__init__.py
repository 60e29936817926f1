"""Dataset readers behind one protocol, an explicit registry and format auto-detection."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from sgs_slam_core.datasets.base import Dataset, DatasetOptions, FrameRecord, RecordDataset
from sgs_slam_core.datasets.registry import DatasetFormat, formats
from sgs_slam_core.datasets.replica import ReplicaDataset
from sgs_slam_core.datasets.scannet import ScanNetDataset
from sgs_slam_core.datasets.tum import TumDataset
from sgs_slam_core.errors import DatasetError

__all__ = [
    "Dataset",
    "DatasetFormat",
    "DatasetOptions",
    "FrameRecord",
    "RecordDataset",
    "ReplicaDataset",
    "ScanNetDataset",
    "TumDataset",
    "dataset_format",
    "detect_format",
    "formats",
    "open_dataset",
]


def detect_format(path: Path) -> str:
    """The name of the format whose files ``path`` holds."""
    if not path.exists():
        raise DatasetError(f"{path} does not exist")
    known = formats()
    for fmt in known.values():
        if fmt.detect(path):
            return fmt.name
    if not path.is_dir():
        raise DatasetError(f"{path} is neither a dataset folder nor a file of a known format ({', '.join(known)})")
    expected = ", ".join(fmt.expects for fmt in known.values())
    raise DatasetError(f"cannot tell the format of {path}: expected {expected}")


def dataset_format(path: Path, fmt: str = "auto") -> DatasetFormat:
    """The format named ``fmt`` (``auto``: detected from what ``path`` holds)."""
    name = detect_format(path) if fmt == "auto" else fmt
    known = formats()
    if name not in known:
        raise DatasetError(f"unknown dataset format {fmt!r}; known: auto, {', '.join(known)}")
    return known[name]


def open_dataset(
    path: str | Path, fmt: str = "auto", options: DatasetOptions | None = None, streams: Mapping[str, str] | None = None
) -> Dataset:
    """Open ``path`` with the reader of format ``fmt`` (``auto`` detects it); ``streams`` rename inputs (bags)."""
    path = Path(path)
    if not path.exists():
        raise DatasetError(f"{path} does not exist")
    return dataset_format(path, fmt).opener(path, options or DatasetOptions(), streams or {})
