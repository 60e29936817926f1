"""The dataset formats ``open_dataset`` knows: the built-in readers and those other packages register.

A package adds a format through the ``sgs_slam_core.dataset_formats`` entry point group (the MCAP
bag reader in ``bags`` does), so the core reads formats it never imports.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from functools import cache
from importlib.metadata import entry_points
from pathlib import Path

from sgs_slam_core.datasets.base import Dataset, DatasetOptions
from sgs_slam_core.datasets.replica import ReplicaDataset
from sgs_slam_core.datasets.scannet import ScanNetDataset
from sgs_slam_core.datasets.tum import TumDataset
from sgs_slam_core.errors import DatasetError

__all__ = ["ENTRY_POINT_GROUP", "DatasetFormat", "formats"]

ENTRY_POINT_GROUP = "sgs_slam_core.dataset_formats"
log = logging.getLogger(__name__)


@dataclass(frozen=True)
class DatasetFormat:
    """One input format: how to recognise it, open it and which config preset suits it."""

    name: str
    expects: str  # what a folder of this format holds, for the error when nothing matches
    detect: Callable[[Path], bool]
    opener: Callable[[Path, DatasetOptions, Mapping[str, str]], Dataset]  # streams: renamed inputs (e.g. bag topics)
    preset: Callable[[Path], str]


def _no_streams(reader: Callable[[Path, DatasetOptions], Dataset], name: str) -> Callable[..., Dataset]:
    def open_reader(path: Path, options: DatasetOptions, streams: Mapping[str, str]) -> Dataset:
        if streams:
            raise DatasetError(f"--topic applies to MCAP bags only, not to a {name} folder")
        return reader(path, options)

    return open_reader


def _is_tum(path: Path) -> bool:
    return (path / "rgb.txt").is_file() and (path / "depth.txt").is_file()


def _is_replica(path: Path) -> bool:
    return (path / "traj.txt").is_file() and ((path / "frames").is_dir() or (path / "results").is_dir())


def _is_scannet(path: Path) -> bool:
    return (path / "color").is_dir() and (path / "pose").is_dir()


def _replica_preset(path: Path) -> str:
    return "synthetic" if (path / "synthetic.yaml").is_file() else "replica"  # our generated scenes


BUILT_IN = (
    DatasetFormat("tum", "rgb.txt (TUM)", _is_tum, _no_streams(TumDataset, "TUM"), lambda _: "tum"),
    DatasetFormat(
        "replica",
        "traj.txt + frames/ or results/ (Replica)",
        _is_replica,
        _no_streams(ReplicaDataset, "Replica"),
        _replica_preset,
    ),
    DatasetFormat(
        "scannet",
        "color/ + pose/ (ScanNet)",
        _is_scannet,
        _no_streams(ScanNetDataset, "ScanNet"),
        lambda _: "scannet",
    ),
)


@cache
def formats() -> dict[str, DatasetFormat]:
    """Every format by name: the built-in ones, then the registered ones (a plugin that fails is logged, skipped)."""
    found = {f.name: f for f in BUILT_IN}
    for point in entry_points(group=ENTRY_POINT_GROUP):
        try:
            plugin = point.load()
        except Exception as err:  # a broken or outdated plugin must not take the built-in readers down
            log.warning("dataset format %s (%s) is not available: %s", point.name, point.value, err)
            continue
        if not isinstance(plugin, DatasetFormat):
            log.warning("dataset format %s (%s) is not a DatasetFormat; ignored", point.name, point.value)
            continue
        found.setdefault(plugin.name, plugin)
    return found
