"""The gravity-aligned map frame: mount poses, the floor plane fit, the levelled first pose."""

import math

import numpy as np
import pytest

from sgs_slam_core.datasets import open_dataset
from sgs_slam_core.errors import ShapeError
from sgs_slam_core.geometry import Intrinsics
from sgs_slam_core.geometry.gravity import (
    OPTICAL_IN_BODY,
    FloorSettings,
    MapAlignment,
    fit_floor_plane,
    initial_map_pose,
    levelled_pose,
    pose_from_xyz_rpy,
    rpy_to_matrix,
)

K = Intrinsics(fx=200.0, fy=200.0, cx=79.5, cy=59.5, width=160, height=120)
MOUNT = pose_from_xyz_rpy(OPTICAL_IN_BODY)


def plane_depth(k: Intrinsics, normal, height: float) -> np.ndarray:  # [H, W] m
    """Depth of the plane ``normal . p = -height`` seen by a camera at the origin (0 where it is not hit)."""
    u, v = np.meshgrid(np.arange(k.width), np.arange(k.height))
    rays = np.stack([(u - k.cx) / k.fx, (v - k.cy) / k.fy, np.ones_like(u, dtype=float)], axis=-1)
    t = -height / (rays @ np.asarray(normal, dtype=float))
    return np.where((t > 0) & (t < 20), t, 0.0).astype(np.float32)


def angle_deg(a, b) -> float:
    a, b = np.asarray(a) / np.linalg.norm(a), np.asarray(b) / np.linalg.norm(b)
    return math.degrees(math.acos(np.clip(a @ b, -1, 1)))


def test_rpy_is_tf2s_convention_and_the_optical_mount_is_rep103():
    # camera optical frame (z forward, x right, y down) in a body frame (x forward, y left, z up)
    r = MOUNT[:3, :3]
    np.testing.assert_allclose(r @ [0, 0, 1], [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(r @ [1, 0, 0], [0, -1, 0], atol=1e-12)
    np.testing.assert_allclose(r @ [0, 1, 0], [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(rpy_to_matrix(0, 0, math.pi / 2) @ [1, 0, 0], [0, 1, 0], atol=1e-12)  # yaw about z
    np.testing.assert_allclose(rpy_to_matrix(0, math.pi / 2, 0) @ [1, 0, 0], [0, 0, -1], atol=1e-12)  # pitch about y


def test_pose_from_quaternion_equals_pose_from_rpy():
    rpy = pose_from_xyz_rpy([1, 2, 3, 0.3, -0.2, 1.1])
    # the same rotation as a quaternion (x y z w), scaled: it is normalised
    from msg_adapters.pose import _matrix_to_quat_xyzw

    q = np.array(_matrix_to_quat_xyzw(rpy[:3, :3])) * 3.0
    np.testing.assert_allclose(pose_from_xyz_rpy([1, 2, 3, *q]), rpy, atol=1e-12)
    with pytest.raises(ShapeError, match=r"6 .* or 7"):
        pose_from_xyz_rpy([0, 0, 0, 1])
    with pytest.raises(ShapeError, match="zero"):
        pose_from_xyz_rpy([0, 0, 0, 0, 0, 0, 0])


@pytest.mark.parametrize("tilt_deg", [0.0, 12.0, 25.0])
def test_floor_fit_recovers_a_tilted_floor_exactly(tilt_deg):
    # camera 1.3 m above the floor, pitched down by tilt_deg: the floor normal (up) in camera coordinates
    t = math.radians(tilt_deg)
    up = np.array([0.0, -math.cos(t), -math.sin(t)])  # optical y is down, z forward: looking down, up is behind
    depth = plane_depth(K, up, 1.3)
    plane = fit_floor_plane(depth, K, np.array([0.0, -1.0, 0.0]))
    assert plane is not None
    assert angle_deg(plane.normal, up) < 0.01
    assert abs(plane.height_m - 1.3) < 1e-4
    assert plane.inlier_fraction > 0.3
    assert abs(plane.tilt_deg(np.array([0.0, -1.0, 0.0])) - tilt_deg) < 0.01
    # the levelled first pose: z up, the camera 1.3 m above the origin, pitched down by tilt_deg
    pose = levelled_pose(plane.normal, [0.0, 0.0, 1.0], plane.height_m)
    np.testing.assert_allclose(pose[:3, 3], [0.0, 0.0, 1.3], atol=1e-4)
    forward = pose[:3, :3] @ [0, 0, 1]
    assert abs(math.degrees(math.asin(-forward[2])) - tilt_deg) < 0.01 and abs(forward[1]) < 1e-9


def test_a_wall_or_a_ceiling_is_not_a_floor():
    wall = plane_depth(K, [0.0, 0.0, -1.0], 2.0)  # 2 m ahead, facing the camera
    assert fit_floor_plane(wall, K, np.array([0.0, -1.0, 0.0])) is None
    ceiling = plane_depth(K, [0.0, 1.0, 0.0], 1.2)  # 1.2 m above: its normal points down
    assert fit_floor_plane(ceiling, K, np.array([0.0, -1.0, 0.0])) is None
    steep = plane_depth(K, [0.0, -math.cos(math.radians(50)), -math.sin(math.radians(50))], 1.0)  # 50 deg down
    assert fit_floor_plane(steep, K, np.array([0.0, -1.0, 0.0]), FloorSettings(max_tilt_deg=30)) is None
    assert fit_floor_plane(steep, K, np.array([0.0, -1.0, 0.0]), FloorSettings(max_tilt_deg=60)) is not None
    # no floor: MapAlignment.FLOOR falls back to the mount
    pose, plane = initial_map_pose(MapAlignment.FLOOR, wall, K, MOUNT)
    assert plane is None and np.array_equal(pose, MOUNT)


def test_the_floor_below_a_table_wins():
    # the floor 1.4 m below the camera and a table top 0.7 m below it covering as many pixels
    up = np.array([0.0, -1.0, 0.0])
    floor, table = plane_depth(K, up, 1.4), plane_depth(K, up, 0.7)
    v = np.arange(K.height)[:, None]
    depth = np.where(v < 60 + 30, floor, table)  # the table hides the lowest rows
    depth[: K.height // 2 + 2] = 0  # nothing above the horizon
    plane = fit_floor_plane(depth, K, up)
    assert plane is not None and abs(plane.height_m - 1.4) < 1e-3


def test_alignment_modes():
    depth = plane_depth(K, [0.0, -1.0, 0.0], 1.5)
    assert np.array_equal(initial_map_pose(MapAlignment.OPTICAL, depth, K, MOUNT)[0], np.eye(4))
    mount = pose_from_xyz_rpy([0.2, -0.1, 1.0, *OPTICAL_IN_BODY[3:]])
    assert np.array_equal(initial_map_pose(MapAlignment.MOUNT, depth, K, mount)[0], mount)
    pose, plane = initial_map_pose(MapAlignment.FLOOR, depth, K, mount)
    # levelled: the floor's height, not the mount's; the body's x/y stay at the origin's
    assert plane is not None
    np.testing.assert_allclose(pose, pose_from_xyz_rpy([0.2, -0.1, 1.5, *OPTICAL_IN_BODY[3:]]), atol=1e-6)


def test_levelling_on_the_synthetic_room(tiny_scene):
    """The room's z is up and its floor at z = 0: every frame's levelled pose agrees with the ground truth."""
    ds = open_dataset(tiny_scene)
    for i in range(len(ds)):
        f = ds[i]
        pose, plane = initial_map_pose(MapAlignment.FLOOR, f.depth, f.intrinsics, MOUNT)
        assert plane is not None, f"frame {i}"
        gt_up, up = f.gt_c2w[:3, :3].T @ [0, 0, 1], pose[:3, :3].T @ [0, 0, 1]
        assert angle_deg(gt_up, up) < 1.0, f"frame {i}"
        assert abs(pose[2, 3] - f.gt_c2w[2, 3]) < 0.05, f"frame {i}"


@pytest.mark.data
def test_levelling_on_real_kinect_depth(tum_teddy):
    """TUM fr3/teddy: the motion-capture frame's z is up; the levelled up agrees within 5 degrees."""
    ds = open_dataset(tum_teddy)
    for i in (15, 60, 120, 180):
        f = ds[i]
        pose, plane = initial_map_pose(MapAlignment.FLOOR, f.depth, f.intrinsics, MOUNT)
        assert plane is not None, f"frame {i}"
        assert angle_deg(f.gt_c2w[:3, :3].T @ [0, 0, 1], pose[:3, :3].T @ [0, 0, 1]) < 5.0, f"frame {i}"
