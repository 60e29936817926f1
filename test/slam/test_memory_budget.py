"""The memory budget: the keyframe store (compact labels, caps, which keyframe leaves) and Gaussian spacing."""

import dataclasses

import numpy as np
import pytest
import torch

from sgs_slam_core.config import load_config
from sgs_slam_core.config.sections import DensifySettings, KeyframeSettings
from sgs_slam_core.datasets import open_dataset
from sgs_slam_core.errors import ConfigError
from sgs_slam_core.frame import CompactFrame, compact_labels
from sgs_slam_core.geometry import Intrinsics
from sgs_slam_core.mapio import load_map, save_map
from sgs_slam_core.slam.keyframe_store import KeyframeStore, view_points
from sgs_slam_core.slam.system import Slam

from ..conftest import FAST_SLAM

K = Intrinsics(50.0, 50.0, 31.5, 23.5, 64, 48)


def looking(index: int, yaw_deg: float, label: int = 1) -> CompactFrame:
    """A keyframe turned ``yaw_deg`` about the vertical, seeing a wall 2 m ahead everywhere."""
    a = np.radians(yaw_deg)
    c2w = np.eye(4)
    c2w[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
    depth = np.full((48, 64), 10000, np.uint16)  # 2 m
    labels = np.full((48, 64), label, np.int64)
    return CompactFrame(
        index, index, K, np.zeros((48, 64, 3), np.uint8), depth, compact_labels(labels), np.linalg.inv(c2w)
    )


def test_labels_take_the_smallest_type_that_holds_them():
    assert compact_labels(np.array([[0, 40]])).dtype == np.uint8
    assert compact_labels(np.array([[0, 300]])).dtype == np.uint16
    assert compact_labels(np.array([[-1, 70000]])).dtype == np.int32
    assert np.array_equal(compact_labels(np.array([[7, 300]])), [[7, 300]])
    assert looking(0, 0).nbytes == 64 * 48 * (3 + 2 + 1)


def test_view_points_lie_on_the_seen_surface():
    pts = view_points(looking(0, 90))
    assert pts.shape == (256, 3)
    assert np.allclose(pts[:, 0], 2.0)  # turned 90 degrees: the wall is at x = 2 m


def test_a_revisited_view_leaves_before_a_view_seen_once():
    """Four directions, then the third again: the old look at it goes, not the oldest keyframe."""
    store = KeyframeStore(KeyframeSettings(max_keyframes=4, keep_recent=1))
    for i, yaw in enumerate((0, 90, 180, 270)):
        assert store.add(looking(i, yaw)) == []
    assert store.add(looking(4, 180)) == [2]
    assert [kf.index for kf in store] == [0, 1, 3, 4]
    assert store.stats().evicted == 1 and store.stats().added == 5
    assert [i for i, _ in store.poses()] == [0, 1, 2, 3, 4]
    assert np.allclose(np.linalg.inv(store.poses()[2][1]), looking(2, 180).w2c)


def test_other_classes_make_a_view_less_redundant():
    """Two equally overlapping old views: the one whose labels match the new view leaves."""
    store = KeyframeStore(KeyframeSettings(max_keyframes=3, keep_recent=1))
    store.add(looking(0, 0, label=3))
    store.add(looking(1, 2, label=1))
    store.add(looking(2, 180))
    assert store.add(looking(3, 1, label=1)) == [1]


def test_the_byte_cap_holds_and_the_newest_stay():
    per = looking(0, 0).nbytes
    store = KeyframeStore(KeyframeSettings(max_keyframes=None, max_megabytes=3.5 * per / 2**20, keep_recent=2))
    for i in range(10):
        store.add(looking(i, 90 * i))
    assert len(store) == 3 and store.nbytes == 3 * per
    assert [kf.index for kf in store][-2:] == [8, 9]
    with_protection = KeyframeStore(KeyframeSettings(max_keyframes=2, keep_recent=2))
    for i in range(5):
        with_protection.add(looking(i, 0))
    assert len(with_protection) == 2 and with_protection[0].index == 3 and with_protection[-1].index == 4


@pytest.mark.parametrize(
    "change",
    [{"max_keyframes": 1}, {"max_keyframes": 3, "keep_recent": 4}, {"max_megabytes": 0.0}, {"keep_recent": -1}],
)
def test_caps_are_validated(change):
    with pytest.raises(ConfigError):
        dataclasses.replace(KeyframeSettings(), **change)


def test_slam_holds_the_capped_store_and_saves_every_pose(tiny_scene, tmp_path):
    data = open_dataset(tiny_scene)
    caps = ["keyframes.max_keyframes=2", "keyframes.keep_recent=1"]
    slam = Slam(load_config("synthetic", overrides=[*FAST_SLAM, *caps]), data.label_table)
    for i in range(len(data)):
        slam.process(data[i])
    assert len(slam.keyframes) == 2 and slam.keyframes.stats().evicted == 1
    assert [i for i, _ in slam.keyframe_poses()] == [0, 4, 9]
    assert slam.keyframes[0].labels.dtype == np.uint8
    save_map(tmp_path / "m.sgsmap", slam.to_map_file())
    loaded = load_map(tmp_path / "m.sgsmap")
    assert [i for i, _ in loaded.keyframes] == [0, 4, 9] and len(loaded.keyframe_images) == 2
    assert loaded.keyframe_images[0].labels.dtype == np.uint8
    again = Slam(load_config("synthetic", overrides=[*FAST_SLAM, *caps]), data.label_table)
    again.load_map(loaded)
    assert [kf.index for kf in again.keyframes] == [kf.index for kf in slam.keyframes]
    assert [i for i, _ in again.to_map_file().keyframes] == [0, 4, 9]


def test_spacing_keeps_one_gaussian_per_cell_and_none_where_the_map_has_one():
    from sgs_slam_core.gaussians import GaussianMap
    from sgs_slam_core.slam.densify import spaced

    points = torch.tensor(
        [[5e-4, 5e-4, 1.0005], [1.5e-3, 5e-4, 1.0005], [0.5005, 5e-4, 1.0005], [0.5005, 5e-4, 2.0005]]
    )
    radii = torch.tensor([0.002, 0.002, 0.002, 0.004])  # cells: 2 mm, 2 mm, 2 mm, 4 mm at spacing 1
    assert spaced(points, radii, None, 1.0).tolist() == [True, False, True, True]
    one = GaussianMap.empty(3)
    z = torch.zeros(1, dtype=torch.long)
    existing = GaussianMap(
        torch.tensor([[0.5015, 5e-4, 1.0005]]),
        torch.zeros(1, 1),
        torch.zeros(1),
        torch.zeros(1, 3),
        torch.zeros(1, 3),
        z,
        z,
    )
    assert spaced(points, radii, existing, 1.0).tolist() == [True, False, False, True]
    assert spaced(points, radii, one, 1.0).tolist() == [True, False, True, True]
    assert spaced(points, radii, existing, 1e-3).tolist() == [True, True, True, True]  # 1 mm cells
    assert not spaced(points, radii, existing, 2000.0).any()  # 4 m and 8 m cells: all share the existing one's


def test_spacing_is_validated():
    with pytest.raises(ConfigError):
        DensifySettings(min_spacing=0.0)


def test_over_budget_drops_the_least_opaque_and_never_a_locked_class():
    from sgs_slam_core.gaussians import GaussianMap
    from sgs_slam_core.slam.densify import over_budget

    n = 5
    logits = torch.tensor([0.0, -3.0, 2.0, -5.0, 1.0])
    labels = torch.tensor([1, 1, 2, 7, 2])
    g = GaussianMap(
        torch.zeros(n, 3),
        torch.zeros(n, 1),
        logits,
        torch.zeros(n, 3),
        torch.zeros(n, 3),
        labels,
        torch.zeros(n, dtype=torch.long),
    )
    assert not over_budget(g, 1, 6).any()
    assert over_budget(g, 2, 4).tolist() == [True, True, False, True, False]
    assert over_budget(g, 2, 4, frozenset({7})).tolist() == [True, True, False, False, True]
    assert over_budget(g, 9, 4, frozenset({2})).tolist() == [True, True, False, True, False]  # the cap yields


def test_slam_keeps_the_map_under_its_gaussian_cap(tiny_scene):
    data = open_dataset(tiny_scene)
    slam = Slam(load_config("synthetic", overrides=[*FAST_SLAM, "densify.max_gaussians=1500"]), data.label_table)
    for i in range(len(data)):
        step = slam.process(data[i])
        assert step.num_gaussians <= max(1500, step.map.added)  # mapping only prunes
    assert slam.num_gaussians > 1000
    with pytest.raises(ConfigError):
        DensifySettings(max_gaussians=0)
