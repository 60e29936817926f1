"""ORB features with depth, PnP between views, the feature start and the feature check."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from sgs_slam_core.config.sections import FeatureSettings, MotionSettings
from sgs_slam_core.frame_data import FrameTensors
from sgs_slam_core.geometry.se3 import rotation_angle_deg
from sgs_slam_core.labels import LabelTable
from sgs_slam_core.semantics import SemanticCodec, SemanticSettings
from sgs_slam_core.slam.feature_odometry import FeatureOdometry
from sgs_slam_core.slam.features import MAX_DISTANCE, extract_features, match_features, solve_motion
from sgs_slam_core.slam.motion import MotionModel
from sgs_slam_core.slam.pose import predict_constant_velocity

from .views import relative, room_frame

SETTINGS = FeatureSettings()


def features(i: int):
    f = room_frame(i)
    return extract_features(f.rgb, f.depth, f.intrinsics, SETTINGS)


def pose_error(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(degrees, metres) between two poses."""
    e = np.linalg.inv(truth) @ estimate
    return float(rotation_angle_deg(e[:3, :3])), float(np.linalg.norm(e[:3, 3]))


def test_keypoints_carry_the_depth_under_them():
    f = room_frame(0)
    feats = features(0)
    assert 200 <= len(feats) <= SETTINGS.count and feats.descriptors.shape == (len(feats), 32)
    assert feats.has_depth.all()  # the room has depth everywhere
    k = f.intrinsics
    u = np.floor(feats.keypoints[:, 0] + 0.5).astype(int)
    v = np.floor(feats.keypoints[:, 1] + 0.5).astype(int)
    assert np.allclose(feats.points[:, 2], f.depth[v, u])
    assert np.allclose(feats.points[:, 0], (feats.keypoints[:, 0] - k.cx) / k.fx * feats.points[:, 2])


def test_a_keypoint_on_a_depth_hole_takes_a_neighbours_depth_or_none():
    f = room_frame(0)
    holes = f.depth.copy()
    holes[:, ::2] = 0.0  # every other column missing: a neighbour always has depth
    with_holes = extract_features(f.rgb, holes, f.intrinsics, SETTINGS)
    assert with_holes.has_depth.mean() > 0.95
    without = extract_features(f.rgb, np.zeros_like(f.depth), f.intrinsics, SETTINGS)
    assert not without.has_depth.any() and len(without) == len(with_holes)


@pytest.mark.parametrize("apart", [4, 10])
def test_pnp_finds_the_motion_between_two_views(apart):
    a, b = features(0), features(apart)
    matches = match_features(a, b, MAX_DISTANCE)
    motion = solve_motion(a, b, matches, SETTINGS)
    assert motion is not None and motion.inliers >= SETTINGS.min_inliers
    degrees, metres = pose_error(motion.ref_to_query, relative(0, apart))
    # at 160x120 a pixel spans 3 cm at the room's 3.6 m: the start is that coarse, tracking refines it
    assert degrees < 1.5 and metres < 0.1


def test_unrelated_descriptors_give_no_pose():
    a = features(0)
    rng = np.random.default_rng(0)
    scrambled = dataclasses.replace(a, descriptors=rng.integers(0, 256, a.descriptors.shape, dtype=np.uint8))
    matches = match_features(scrambled, features(4), MAX_DISTANCE)
    assert solve_motion(scrambled, features(4), matches, SETTINGS) is None


def test_agreement_is_full_at_the_feature_pose_and_low_far_from_it():
    odometry = FeatureOdometry(SETTINGS)
    first = odometry.view(room_frame(0))
    assert first.c2w is None and first.agreement(np.eye(4), 2.0) is None  # no reference yet
    odometry.accept(first, room_frame(0).gt_c2w)
    view = odometry.view(room_frame(4))
    assert view.c2w is not None and view.inliers >= SETTINGS.min_inliers
    degrees, metres = pose_error(view.c2w, room_frame(4).gt_c2w)
    assert degrees < 1.5 and metres < 0.1
    assert view.agreement(view.c2w, SETTINGS.reprojection_px) == pytest.approx(1.0)
    assert view.agreement(room_frame(4).gt_c2w, SETTINGS.reprojection_px) > 0.8
    turned = room_frame(4).gt_c2w.copy()
    turned[:3, :3] = turned[:3, :3] @ np.array([[0.98, 0, 0.199], [0, 1, 0], [-0.199, 0, 0.98]])  # ~11.5 deg
    assert view.agreement(turned, SETTINGS.reprojection_px) < 0.2


def data_of(i: int) -> FrameTensors:
    codec = SemanticCodec(SemanticSettings(), LabelTable.nyu40())
    return FrameTensors.from_frame(room_frame(i), codec, torch.device("cpu"))


@pytest.mark.parametrize("settings", [FeatureSettings(), FeatureSettings(enabled=False)])
def test_the_feature_pose_starts_tracking_where_the_velocity_guess_is_off(settings):
    """A camera that stops turning: constant velocity overshoots, the features do not."""
    motion = MotionModel(MotionSettings(icp_iterations=()), room_frame(0).gt_c2w, features=settings)
    for i in (0, 4):  # 6 degrees a frame so far ...
        view = motion.view(room_frame(i))
        motion.observe(room_frame(i).stamp_ns, room_frame(i).gt_c2w, None, view)
    frame = dataclasses.replace(room_frame(5), stamp_ns=2 * room_frame(4).stamp_ns)
    view = motion.view(frame)  # ... then 1.5 degrees in the next
    start = motion.start(frame.stamp_ns, data_of(5), view)
    degrees, _ = pose_error(start.c2w, frame.gt_c2w)
    if settings.enabled:
        assert start.from_features and degrees < 1.5
    else:
        assert view is None and not start.from_features and degrees > 4


def test_the_velocity_guess_stays_where_the_features_agree_with_it():
    motion = MotionModel(MotionSettings(icp_iterations=()), room_frame(0).gt_c2w, features=SETTINGS)
    for i in (0, 1, 2):
        view = motion.view(room_frame(i))
        motion.observe(room_frame(i).stamp_ns, room_frame(i).gt_c2w, None, view)
    view = motion.view(room_frame(3))
    assert view.c2w is not None
    start = motion.start(room_frame(3).stamp_ns, data_of(3), view)
    assert not start.from_features
    guess = predict_constant_velocity(room_frame(2).gt_c2w, room_frame(1).gt_c2w)
    assert np.allclose(start.c2w, guess)
