"""A gravity-aligned (z-up) map frame: from a camera mount, or levelled on the first frame's floor.

SLAM's map frame is wherever the first camera pose puts it (``Slam(initial_c2w=...)``). With the
identity that is the first camera's optical frame (x right, y down, z forward), which viewers show
on its side. These helpers choose the first pose so that the map follows REP-103 instead: z up,
x forward (the mount's forward direction projected onto the floor), metres.

- :func:`mount_pose`: the camera's pose in a z-up body frame (``camera_mount``, the
  ``base_link -> camera optical frame`` transform): correct when the body stands level.
- :func:`fit_floor_plane` + :func:`levelled_pose`: the dominant horizontal plane below the camera
  in the first depth image gives the true "up" (the mount only says which plane to look for) and the
  camera's height; the map origin is the floor point below the first camera position.

Numpy only (the depth images are numpy); the plane fit is a small hand-written RANSAC (sample 3
points, score inliers, refit by SVD), as neither OpenCV nor numpy offers one for 3D planes.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from sgs_slam_core.errors import ShapeError
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.geometry.se3 import quat_xyzw_to_matrix

__all__ = [
    "OPTICAL_IN_BODY",
    "FloorPlane",
    "FloorSettings",
    "MapAlignment",
    "fit_floor_plane",
    "initial_map_pose",
    "levelled_pose",
    "mount_pose",
    "pose_from_xyz_rpy",
    "rpy_to_matrix",
]

# base_link -> camera optical frame of a level, forward-looking camera (REP-103: rpy = -pi/2, 0, -pi/2)
OPTICAL_IN_BODY = (0.0, 0.0, 0.0, -math.pi / 2, 0.0, -math.pi / 2)


class MapAlignment(StrEnum):
    """How the map frame is oriented."""

    OPTICAL = "optical"  # the first camera's optical frame (y down, z forward)
    MOUNT = "mount"  # z up: the first pose of the body the camera is mounted on
    FLOOR = "floor"  # z up: levelled on the first frame's floor plane (MOUNT when none is found)


@dataclass(frozen=True)
class FloorSettings:
    """RANSAC floor search in the first depth image."""

    max_tilt_deg: float = 30.0  # the floor normal may differ this much from the mount's "up"
    inlier_m: float = 0.03  # point-to-plane distance of an inlier (m)
    min_fraction: float = 0.05  # of the valid depth pixels that must lie on the plane
    min_height_m: float = 0.1  # the camera must be at least this far above the plane (m)
    hypotheses: int = 2000  # RANSAC samples (a floor on 10 % of the pixels is sampled with 86 % odds)
    max_points: int = 20000  # depth pixels used for the final fit (a regular subsample)
    score_points: int = 4000  # random subset that scores the hypotheses
    seed: int = 0


@dataclass(frozen=True)
class FloorPlane:
    """A plane ``normal . p = -offset`` in camera coordinates (``normal`` points up, unit length)."""

    normal: np.ndarray  # [3] unit vector, camera frame, towards the camera's side of the plane
    height_m: float  # distance of the camera centre above the plane (m)
    inlier_fraction: float  # share of the valid depth pixels on the plane

    def tilt_deg(self, up: np.ndarray) -> float:
        """Angle between this plane's normal and the direction ``up`` [3] (degrees)."""
        cos = float(np.clip(self.normal @ (up / np.linalg.norm(up)), -1.0, 1.0))
        return math.degrees(math.acos(cos))


def rpy_to_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:  # [3, 3]
    """Rotation of fixed-axis roll, pitch, yaw (rad; ``Rz(yaw) Ry(pitch) Rx(roll)``, as tf2 and URDF)."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def pose_from_xyz_rpy(values: Sequence[float]) -> np.ndarray:  # [4, 4]
    """A pose from ``x y z roll pitch yaw`` (m, rad) or ``x y z qx qy qz qw`` (m, unit quaternion)."""
    v = [float(x) for x in values]
    if len(v) not in (6, 7) or not all(math.isfinite(x) for x in v):
        raise ShapeError(f"a pose needs 6 (x y z roll pitch yaw) or 7 (x y z qx qy qz qw) finite numbers, got {v}")
    pose = np.eye(4)
    pose[:3, 3] = v[:3]
    if len(v) == 6:
        pose[:3, :3] = rpy_to_matrix(*v[3:])
        return pose
    pose[:3, :3] = quat_xyzw_to_matrix(*v[3:])
    return pose


def mount_pose(mount: np.ndarray) -> np.ndarray:  # [4, 4] -> [4, 4]
    """First camera pose in a map that coincides with the first pose of the (level) body."""
    return np.asarray(mount, dtype=np.float64).copy()


def _points(depth: np.ndarray, k: Intrinsics, max_points: int) -> np.ndarray:  # [H, W] m -> [N, 3]
    """Back-projected valid depth pixels, a regular subsample of at most ``max_points``."""
    if depth.shape != k.shape:
        raise ShapeError(f"depth is {depth.shape[1]}x{depth.shape[0]} but the intrinsics are {k.width}x{k.height}")
    v, u = np.nonzero(np.isfinite(depth) & (depth > 0))
    step = max(1, math.ceil(len(v) / max_points))
    v, u = v[::step], u[::step]
    z = depth[v, u].astype(np.float64)
    return np.stack([(u - k.cx) / k.fx * z, (v - k.cy) / k.fy * z, z], axis=1)


def fit_floor_plane(
    depth: np.ndarray,  # [H, W] metres, 0 = invalid
    intrinsics: Intrinsics,
    up: np.ndarray,  # [3] the expected "up" in the camera frame (from the mount)
    settings: FloorSettings = FloorSettings(),
) -> FloorPlane | None:
    """The floor: the lowest well-supported plane below the camera, normal within ``max_tilt_deg`` of ``up``.

    "Well supported": at least ``min_fraction`` of the valid pixels and half as many as the best
    plane (so a table top that fills as much of the image does not win). None if there is none.
    """
    up = np.asarray(up, dtype=np.float64)
    up = up / np.linalg.norm(up)
    pts = _points(depth, intrinsics, settings.max_points)
    if len(pts) < 3:
        return None
    rng = np.random.default_rng(settings.seed)
    tri = pts[rng.integers(0, len(pts), size=(settings.hypotheses, 3))]  # [K, 3, 3]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    lengths = np.linalg.norm(normals, axis=1)
    ok = lengths > 1e-12
    normals, tri = normals[ok] / lengths[ok, None], tri[ok]
    normals *= np.sign(normals @ up)[:, None]  # towards "up"
    offsets = -np.einsum("kd,kd->k", normals, tri[:, 0])  # camera height above each plane
    cos_max = math.cos(math.radians(settings.max_tilt_deg))
    keep = (normals @ up >= cos_max) & (offsets >= settings.min_height_m)
    if not keep.any():
        return None
    normals, offsets = normals[keep], offsets[keep]
    sample = pts[rng.choice(len(pts), size=min(len(pts), settings.score_points), replace=False)]
    counts = np.concatenate(
        [
            (np.abs(sample @ normals[i : i + 256].T + offsets[i : i + 256]) < settings.inlier_m).sum(axis=0)
            for i in range(0, len(normals), 256)
        ]
    )
    # the floor is the lowest well-supported plane (a table top may hold as many points)
    supported = counts >= max(settings.min_fraction * len(sample), 0.5 * counts.max(), 3)
    best = int(np.argmax(np.where(supported, offsets, -np.inf)))
    normal, offset = normals[best], float(offsets[best])
    for _ in range(3):  # least-squares refits: the normal is the direction of least spread of the inliers
        inliers = pts[np.abs(pts @ normal + offset) < settings.inlier_m]
        if len(inliers) < 3:
            return None
        centre = inliers.mean(axis=0)
        normal = np.linalg.svd(inliers - centre, full_matrices=False)[2][-1]
        normal *= 1.0 if normal @ up >= 0 else -1.0
        offset = float(-normal @ centre)
    fraction = float((np.abs(pts @ normal + offset) < settings.inlier_m).mean())
    if fraction < settings.min_fraction or normal @ up < cos_max or offset < settings.min_height_m:
        return None
    return FloorPlane(normal=normal, height_m=offset, inlier_fraction=fraction)


def levelled_pose(
    up: np.ndarray,  # [3] unit "up" in the camera frame (the floor normal)
    forward: np.ndarray,  # [3] the direction that becomes map x, camera frame (projected onto the floor)
    height_m: float,  # camera height above the floor (m): the map origin is the floor point below it
) -> np.ndarray:  # [4, 4] c2w of the camera in the z-up map
    """First camera pose in a z-up map whose x axis is ``forward`` levelled onto the floor."""
    z = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    x = np.asarray(forward, dtype=np.float64) - (np.asarray(forward) @ z) * z
    if np.linalg.norm(x) < 1e-6:  # looking straight down: any horizontal x will do
        x = np.array([1.0, 0.0, 0.0]) - z[0] * z
        if np.linalg.norm(x) < 1e-6:
            x = np.array([0.0, 1.0, 0.0]) - z[1] * z
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([x, y, z])  # rows: map axes in camera coordinates -> camera to map rotation
    pose[:3, 3] = [0.0, 0.0, height_m]
    return pose


def initial_map_pose(
    alignment: MapAlignment,
    depth: np.ndarray,  # [H, W] metres of the first frame
    intrinsics: Intrinsics,
    mount: np.ndarray,  # [4, 4] pose of the camera optical frame in the body frame (z up)
    settings: FloorSettings = FloorSettings(),
) -> tuple[np.ndarray, FloorPlane | None]:
    """The first camera pose (c2w [4, 4]) for ``alignment``, and the floor plane it was levelled on."""
    if alignment is MapAlignment.OPTICAL:
        return np.eye(4), None
    if alignment is MapAlignment.MOUNT:
        return mount_pose(mount), None
    rot = np.asarray(mount, dtype=np.float64)[:3, :3]  # camera -> body
    up, forward = rot.T @ np.array([0.0, 0.0, 1.0]), rot.T @ np.array([1.0, 0.0, 0.0])
    plane = fit_floor_plane(depth, intrinsics, up, settings)
    if plane is None:
        return mount_pose(mount), None
    pose = levelled_pose(plane.normal, forward, plane.height_m)
    pose[:2, 3] = np.asarray(mount, dtype=np.float64)[:2, 3]  # the body's first position is above the origin
    return pose, plane
