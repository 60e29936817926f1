"""Shared fixtures. DDS discovery is confined to this machine before anything can import rclpy."""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile
from pathlib import Path

import pytest

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
# nodes stopped by a signal save their map under $ROS_HOME: the tests' nodes (and their children) in a scratch one
os.environ["ROS_HOME"] = tempfile.mkdtemp(prefix="sgs-slam-test-ros-home-")
atexit.register(shutil.rmtree, os.environ["ROS_HOME"], ignore_errors=True)

REPO = Path(__file__).resolve().parents[1]


def shared_data_dir() -> Path:
    """``$SGS_SLAM_DATA`` or the workspace's ``../shared/data``."""
    return Path(os.environ.get("SGS_SLAM_DATA", REPO.parent / "shared" / "data"))


@pytest.fixture
def tum_teddy() -> Path:
    """The real TUM fr3/teddy sample (200 frames); skipped with a reason when absent."""
    path = shared_data_dir() / "tum_fr3_teddy"
    if not (path / "rgb.txt").is_file():
        pytest.skip(f"real TUM sample not found at {path} (set SGS_SLAM_DATA to the folder holding tum_fr3_teddy)")
    return path


@pytest.fixture(scope="session")
def tiny_scene(tmp_path_factory) -> Path:
    """The ``tiny`` synthetic sequence (64x48, 12 frames), generated once per test session."""
    from sgs_slam_core.synthetic import generate, preset_config

    return generate(tmp_path_factory.mktemp("scenes") / "tiny", preset_config("tiny"))


# CI-sized SLAM settings for the tiny scene (the accuracy targets are checked by benchmarks). At
# 64x48 a pixel is 2.5x wider than at the preset's 160x120, so splats grow 10x faster to cover it
# within 15 mapping iterations.
FAST_SLAM = ("tracking.adam.iterations=30", "mapping.iterations=15", "mapping.lr_scales=1e-2")
