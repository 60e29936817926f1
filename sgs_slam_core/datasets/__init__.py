"""Dataset readers behind one protocol, an explicit registry and format auto-detection."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from sgs_slam_core.datasets.base import Dataset, DatasetOptions, FrameRecord, RecordDataset
from sgs_slam_core.datasets.replica import ReplicaDataset
from sgs_slam_core.datasets.scannet import ScanNetDataset
from sgs_slam_core.datasets.tum import TumDataset
from sgs_slam_core.errors import DatasetError

__all__ = [
    "FORMATS",
    "Dataset",
    "DatasetOptions",
    "FrameRecord",
    "RecordDataset",
    "ReplicaDataset",
    "ScanNetDataset",
    "TumDataset",
    "detect_format",
    "open_dataset",
]

Opener = Callable[[Path, DatasetOptions], Dataset]


def _open_mcap(path: Path, options: DatasetOptions) -> Dataset:
    from bags.reader import BagDataset  # noqa: PLC0415 - bags depends on the core, not the reverse

    return BagDataset(path, options)


FORMATS: dict[str, Opener] = {
    "tum": TumDataset,
    "replica": ReplicaDataset,
    "scannet": ScanNetDataset,
    "mcap": _open_mcap,
}


def detect_format(path: Path) -> str:
    """Guess the format of a dataset folder or bag from what it contains."""
    if path.is_file() and path.suffix == ".mcap":
        return "mcap"
    if not path.is_dir():
        raise DatasetError(f"{path} is neither a dataset folder nor an .mcap file")
    if (path / "metadata.yaml").is_file() and any(path.glob("*.mcap")):
        return "mcap"
    if (path / "rgb.txt").is_file() and (path / "depth.txt").is_file():
        return "tum"
    if (path / "traj.txt").is_file() and ((path / "frames").is_dir() or (path / "results").is_dir()):
        return "replica"
    if (path / "color").is_dir() and (path / "pose").is_dir():
        return "scannet"
    raise DatasetError(
        f"cannot tell the format of {path}: expected rgb.txt (TUM), traj.txt + frames/ or results/ (Replica), "
        "color/ + pose/ (ScanNet) or an MCAP bag"
    )


def open_dataset(path: str | Path, fmt: str = "auto", options: DatasetOptions | None = None) -> Dataset:
    """Open ``path`` with the reader registered for ``fmt`` (``auto`` detects it)."""
    path = Path(path)
    if not path.exists():
        raise DatasetError(f"{path} does not exist")
    name = detect_format(path) if fmt == "auto" else fmt
    if name not in FORMATS:
        raise DatasetError(f"unknown dataset format {fmt!r}; known: auto, {', '.join(FORMATS)}")
    return FORMATS[name](path, options or DatasetOptions())
