"""Camera model and rigid-body maths."""

from sgs_slam_core.geometry.camera import Intrinsics, backproject, pixel_grid, vertex_map
from sgs_slam_core.geometry.se3 import (
    quat_multiply,
    quat_normalize,
    quat_to_rotmat,
    rotmat_to_quat,
    se3_exp,
    se3_from_rt,
    se3_inverse,
    so3_exp,
    so3_log,
    transform_points,
)
from sgs_slam_core.geometry.views import look_at, orbit_poses

__all__ = [
    "Intrinsics",
    "backproject",
    "look_at",
    "orbit_poses",
    "pixel_grid",
    "quat_multiply",
    "quat_normalize",
    "quat_to_rotmat",
    "rotmat_to_quat",
    "se3_exp",
    "se3_from_rt",
    "se3_inverse",
    "so3_exp",
    "so3_log",
    "transform_points",
    "vertex_map",
]
