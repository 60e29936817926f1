"""The depth ICP's reference frame: kept while the camera stays near it, replaced when it moves on or fails."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from sgs_slam_core.config import load_config
from sgs_slam_core.config.sections import MotionSettings
from sgs_slam_core.datasets import open_dataset
from sgs_slam_core.errors import ConfigError
from sgs_slam_core.geometry import se3_exp
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.geometry.views import views_near
from sgs_slam_core.slam.icp_init import IcpInit, ReferencePolicy
from sgs_slam_core.slam.system import Slam

K = Intrinsics(40.0, 40.0, 15.5, 11.5, 32, 24)


def pose(tx: float = 0.0, yaw_deg: float = 0.0) -> np.ndarray:  # c2w [4, 4]
    xi = torch.tensor([tx, 0.0, 0.0, 0.0, np.radians(yaw_deg), 0.0], dtype=torch.float64)
    return se3_exp(xi).numpy()


def test_views_near_a_pose_are_those_close_enough_and_turned_little_enough():
    views = [pose(), pose(0.2, 10.0), pose(0.3), pose(0.0, 13.0)]
    centres = np.stack([v[:3, 3] for v in views])
    axes = np.stack([v[:3, 2] for v in views])
    assert views_near(centres, axes, pose(), 0.25, 12.0).tolist() == [True, True, False, False]
    assert views_near(centres, axes, pose(0.3), 0.25, 12.0).tolist() == [False, True, True, False]
    assert views_near(centres[:0], axes[:0], pose(), 0.25, 12.0).shape == (0,)


def test_a_reference_serves_poses_within_its_distance_and_angle_and_either_zero_keeps_none():
    policy = ReferencePolicy(distance_m=0.25, angle_deg=12.0)
    assert policy.keeps(pose(), pose(0.2, 10.0))
    assert not policy.keeps(pose(), pose(0.3))  # moved too far
    assert not policy.keeps(pose(), pose(0.0, 13.0))  # turned too far
    assert not ReferencePolicy().keeps(pose(), pose())  # frame to frame: every frame is the next reference
    assert not ReferencePolicy(0.25, 0.0).keeps(pose(), pose())


def wall(depth_m: float) -> torch.Tensor:  # [H, W] m
    """A slanted wall: enough structure for the ICP to find correspondences."""
    u = torch.arange(K.width, dtype=torch.float32)
    return (depth_m + 0.02 * u).expand(K.height, K.width).contiguous()


def test_the_icp_keeps_its_reference_until_the_camera_moves_on_or_the_alignment_fails():
    icp = IcpInit(MotionSettings().icp, 0.3, policy=ReferencePolicy(0.25, 12.0))
    assert icp.reference_c2w is None
    icp.remember(wall(2.0), K, pose())
    icp.remember(wall(2.0), K, pose(0.1))  # near: the first frame stays the reference
    assert np.array_equal(icp.reference_c2w, pose())
    _, outcome = icp.refine(wall(2.0), K, pose(0.1))
    assert outcome is not None and outcome.used
    icp.remember(wall(2.0), K, pose(0.3))  # moved on
    assert np.array_equal(icp.reference_c2w, pose(0.3))
    _, failed = icp.refine(torch.zeros(K.height, K.width), K, pose(0.3))  # no depth: nothing aligns
    assert failed is not None and not failed.used
    icp.remember(wall(2.0), K, pose(0.31))  # near, but the reference just failed: replaced
    assert np.array_equal(icp.reference_c2w, pose(0.31))
    icp.remember(wall(2.0), K, pose(0.32))  # the alignment was not tried since: kept
    assert np.array_equal(icp.reference_c2w, pose(0.31))
    other = Intrinsics(20.0, 20.0, 7.5, 5.5, 16, 12)
    icp.remember(torch.full((12, 16), 2.0), other, pose(0.32))  # another camera: replaced
    assert np.array_equal(icp.reference_c2w, pose(0.32))


def test_a_start_left_on_the_device_is_the_refined_pose_and_its_settled_outcome_keeps_or_replaces_the_reference():
    icp = IcpInit(MotionSettings().icp, 0.3, policy=ReferencePolicy(0.25, 12.0))
    assert icp.start(wall(2.0), K, pose()) is None  # no reference yet
    icp.remember(wall(2.0), K, pose())
    for depth in (wall(2.0), torch.zeros(K.height, K.width)):  # aligns; nothing to align (the prediction)
        on_device = icp.start(depth, K, pose(0.1))
        c2w, outcome = icp.refine(depth, K, pose(0.1))
        assert np.allclose(on_device.c2w.numpy(), c2w, atol=1e-12)
        expected = [float(outcome.used), outcome.inlier_fraction, outcome.rms_m]
        assert on_device.outcome.tolist() == pytest.approx(expected)
    assert not outcome.used and np.array_equal(c2w, pose(0.1))
    icp.settle(True)
    icp.remember(wall(2.0), K, pose(0.05))  # near, and the alignment was used: kept
    assert np.array_equal(icp.reference_c2w, pose())
    icp.settle(False)
    icp.remember(wall(2.0), K, pose(0.06))  # near, but the alignment was not used: replaced
    assert np.array_equal(icp.reference_c2w, pose(0.06))


def test_frame_to_frame_replaces_the_reference_with_every_tracked_frame():
    icp = IcpInit(MotionSettings().icp, 0.3)
    for tx in (0.0, 0.001, 0.002):
        icp.remember(wall(2.0), K, pose(tx))
        assert np.array_equal(icp.reference_c2w, pose(tx))


@pytest.mark.parametrize(
    "override",
    ["motion.icp_reference_distance_m=-0.1", "motion.icp_reference_angle_deg=91", "motion.icp_reference_angle_deg=-1"],
)
def test_reference_settings_out_of_range_are_refused(override):
    with pytest.raises(ConfigError, match="icp_reference"):
        load_config("synthetic", None, [override])


def test_the_slam_aligns_frames_to_a_kept_reference_by_its_settings(tiny_scene, monkeypatch):
    """The tiny scene's first six frames stay within the synthetic preset's 25 cm and 12 degrees."""
    tiny = open_dataset(tiny_scene)
    references = []
    remember = IcpInit.remember

    def spy(self, depth, intrinsics, c2w):
        remember(self, depth, intrinsics, c2w)
        references.append(self.reference_c2w.tobytes())

    monkeypatch.setattr(IcpInit, "remember", spy)
    for override, expected in (("motion.icp_reference_angle_deg=12", 1), ("motion.icp_reference_angle_deg=0", 6)):
        references.clear()
        slam = Slam(load_config("synthetic", None, ["mapping.iterations=3", "device=cpu", override]), tiny.label_table)
        for i in range(6):
            slam.process(tiny[i])
        assert len(references) == 6 and len(set(references)) == expected
