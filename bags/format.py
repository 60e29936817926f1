"""MCAP bags as a dataset format of ``sgs_slam_core`` (registered through an entry point in setup.py)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from bags.errors import BagError
from bags.layout import BagTopics
from bags.preset import read_bag_preset
from bags.reader import open_bag
from sgs_slam_core.datasets.base import Dataset, DatasetOptions
from sgs_slam_core.datasets.registry import DatasetFormat

__all__ = ["MCAP_FORMAT"]


def is_bag(path: Path) -> bool:
    """An ``.mcap`` file, or a rosbag2 folder (``metadata.yaml`` beside an ``.mcap``)."""
    if path.is_file():
        return path.suffix == ".mcap"
    return path.is_dir() and (path / "metadata.yaml").is_file() and any(path.glob("*.mcap"))


def open_streams(path: Path, options: DatasetOptions, streams: Mapping[str, str]) -> Dataset:
    """Open a bag; ``streams`` map a stream (color, camera_info, depth, semantic, pose) to its topic."""
    try:
        topics = BagTopics(**streams)
    except TypeError as err:
        raise BagError(
            f"unknown stream in {sorted(streams)}; streams: color, camera_info, depth, semantic, pose"
        ) from err
    return open_bag(path, options, topics)


def bag_preset(path: Path) -> str:
    """The preset the converter recorded, else ``tum`` (a bag recorded elsewhere: a real RGB-D camera)."""
    return read_bag_preset(path) or "tum"


MCAP_FORMAT = DatasetFormat("mcap", "an MCAP bag", is_bag, open_streams, bag_preset)
