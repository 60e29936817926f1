"""Shared inputs of the robustness matrix: a finished tiny run and the tiny scene as a bag (made once)."""

from __future__ import annotations

import pytest

from bags import convert
from sgs_slam_core.cli import main
from sgs_slam_core.datasets import open_dataset

from .inputs import FAST_RUN, Env


@pytest.fixture(scope="session")
def finished_run(tiny_scene, tmp_path_factory):
    out = tmp_path_factory.mktemp("robust") / "run"
    assert main(["run", str(tiny_scene), "--out", str(out), *FAST_RUN]) == 0
    return out


@pytest.fixture(scope="session")
def tiny_bag(tiny_scene, tmp_path_factory):
    out = tmp_path_factory.mktemp("robust") / "bag"
    convert(open_dataset(tiny_scene), out, compress=False, max_frames=4)
    return out


@pytest.fixture
def env(tmp_path, tiny_scene, finished_run, tiny_bag):
    return Env(tmp_path, tiny_scene, finished_run, tiny_bag)
