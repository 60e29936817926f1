"""Edits of a live map: locked classes do not grow back, moved objects stay put, undo, resume."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from sgs_slam_core.config import load_config
from sgs_slam_core.datasets import open_dataset
from sgs_slam_core.editing import EditError, EditKind, EditRequest, Selection
from sgs_slam_core.mapio import MapFile, load_map, save_map
from sgs_slam_core.metrics import ate
from sgs_slam_core.slam.system import Slam

from ..conftest import FAST_SLAM

TABLE_ID, CABINET_ID = 7, 3  # NYU40 classes visible through the tiny sequence
HALF = 6


@pytest.fixture(scope="module")
def tiny(tiny_scene):
    return open_dataset(tiny_scene)


def new_slam(tiny) -> Slam:
    return Slam(load_config("synthetic", overrides=list(FAST_SLAM)), tiny.label_table)


@pytest.fixture(scope="module")
def first_half(tiny) -> MapFile:
    slam = new_slam(tiny)
    for i in range(HALF):
        slam.process(tiny[i])
    return slam.to_map_file()


@pytest.fixture
def resumed(tiny, first_half) -> Slam:
    slam = new_slam(tiny)
    slam.load_map(first_half)
    return slam


def continue_run(slam: Slam, tiny) -> list[np.ndarray]:
    return [slam.process(tiny[i]).c2w for i in range(HALF, len(tiny))]


def test_resume_keeps_tracking_and_mapping_in_a_saved_map(tiny, first_half, resumed, tmp_path):
    save_map(tmp_path / "half.sgsmap", first_half)
    slam = new_slam(tiny)
    slam.load_map(load_map(tmp_path / "half.sgsmap"))
    assert slam.num_gaussians == len(first_half.gaussians)
    poses = [c2w for _, _, c2w in first_half.trajectory] + continue_run(slam, tiny)
    gt = np.stack([tiny[i].gt_c2w for i in range(len(tiny))])
    assert ate(np.stack(poses), gt).rmse < 0.015
    assert slam.num_gaussians != len(first_half.gaussians)  # mapping went on
    again = slam.to_map_file()  # the resumed map keeps the whole history and the frame counter
    assert [i for i, _, _ in again.trajectory] == list(range(len(tiny)))
    assert again.frames_processed == len(tiny) == slam.frames_processed
    assert [i for i, _ in again.keyframes][: len(first_half.keyframes)] == [i for i, _ in first_half.keyframes]


def test_a_removed_class_does_not_grow_back(tiny, resumed):
    record = resumed.apply_edit(EditRequest(EditKind.REMOVE, Selection(("table",))))
    assert record.labels == (TABLE_ID,) and record.count > 50
    assert resumed.locked_labels == {TABLE_ID}
    poses = continue_run(resumed, tiny)
    assert int((resumed.gaussians.labels == TABLE_ID).sum()) == 0
    view = resumed.render_view(poses[-1])
    labels = resumed.decode(view.semantic)
    assert float((labels == TABLE_ID).float().mean()) < 0.01  # the table is gone from the rendered labels
    gt = np.stack([tiny[i].gt_c2w for i in range(HALF, len(tiny))])
    assert ate(np.stack(poses), gt).rmse < 0.02  # tracking ignores the table's pixels and keeps going


def test_without_the_lock_the_removed_class_comes_back(tiny, resumed):
    resumed.apply_edit(EditRequest(EditKind.REMOVE, Selection((TABLE_ID,))))
    resumed.edits.clear()  # the user resets the edit
    continue_run(resumed, tiny)
    assert int((resumed.gaussians.labels == TABLE_ID).sum()) > 20


def test_a_moved_object_stays_frozen_where_it_was_put_and_undo_brings_it_back(tiny, resumed):
    before = resumed.gaussians.select(resumed.gaussians.labels == CABINET_ID)
    record = resumed.apply_edit(EditRequest(EditKind.MOVE, Selection((CABINET_ID,)), translation=(0.3, 0.0, 0.0)))
    moved = resumed.gaussians.select(resumed.gaussians.labels == CABINET_ID)
    torch.testing.assert_close(moved.means - before.means, torch.tensor([[0.3, 0.0, 0.0]]).expand_as(before.means))
    continue_run(resumed, tiny)
    after = resumed.gaussians.select(resumed.gaussians.labels == CABINET_ID)
    for name in ("means", "log_scales", "logit_opacities", "colors", "semantics", "birth_frame"):
        assert torch.equal(getattr(after, name), getattr(moved, name)), name  # frozen, not re-grown
    undone = resumed.undo_edit()
    assert undone.kind is EditKind.MOVE and undone.count == record.count and not resumed.locked_labels
    restored = resumed.gaussians.select(resumed.gaussians.labels == CABINET_ID)
    assert torch.equal(restored.means, before.means)
    with pytest.raises(EditError, match="no edit to undo"):
        resumed.undo_edit()


def test_undo_of_a_removal_re_adds_the_object_and_keeps_later_mapping(tiny, resumed):
    count = int((resumed.gaussians.labels == TABLE_ID).sum())
    resumed.apply_edit(EditRequest(EditKind.REMOVE, Selection((TABLE_ID,))))
    resumed.process(tiny[HALF])
    others = resumed.num_gaussians
    resumed.undo_edit()
    assert int((resumed.gaussians.labels == TABLE_ID).sum()) == count
    assert resumed.num_gaussians == others + count


def test_locks_are_saved_with_the_map(tiny, resumed, tmp_path):
    resumed.apply_edit(EditRequest(EditKind.REMOVE, Selection((TABLE_ID,))))
    save_map(tmp_path / "edited.sgsmap", resumed.to_map_file())
    again = new_slam(tiny)
    again.load_map(load_map(tmp_path / "edited.sgsmap"))
    assert again.locked_labels == {TABLE_ID}
    continue_run(again, tiny)
    assert int((again.gaussians.labels == TABLE_ID).sum()) == 0
