"""geometry_msgs/PoseStamped <-> 4x4 camera-to-world matrices."""

from __future__ import annotations

from typing import Any

import numpy as np

from msg_adapters.errors import AdapterError
from msg_adapters.stamps import ns_to_stamp
from sgs_slam_core.errors import ShapeError
from sgs_slam_core.geometry.se3 import quat_xyzw_to_matrix

__all__ = ["c2w_to_pose", "pose_to_c2w"]


def _matrix_to_quat_xyzw(r: np.ndarray) -> tuple[float, float, float, float]:
    tr = np.trace(r)
    cands = [
        (1 + tr, r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]),
        (r[2, 1] - r[1, 2], 1 + r[0, 0] - r[1, 1] - r[2, 2], r[0, 1] + r[1, 0], r[0, 2] + r[2, 0]),
        (r[0, 2] - r[2, 0], r[0, 1] + r[1, 0], 1 - r[0, 0] + r[1, 1] - r[2, 2], r[1, 2] + r[2, 1]),
        (r[1, 0] - r[0, 1], r[0, 2] + r[2, 0], r[1, 2] + r[2, 1], 1 - r[0, 0] - r[1, 1] + r[2, 2]),
    ]
    pivots = [1 + tr, 1 + r[0, 0] - r[1, 1] - r[2, 2], 1 - r[0, 0] + r[1, 1] - r[2, 2], 1 - r[0, 0] - r[1, 1] + r[2, 2]]
    w, x, y, z = np.asarray(cands[int(np.argmax(pivots))])
    q = np.array([x, y, z, w]) / np.linalg.norm([w, x, y, z])
    if q[3] < 0:
        q = -q
    return float(q[0]), float(q[1]), float(q[2]), float(q[3])


def pose_to_c2w(msg: Any) -> np.ndarray:  # [4, 4] float64
    """Camera-to-world matrix of a PoseStamped (or a Pose)."""
    pose = msg.pose if hasattr(msg, "pose") else msg
    p, q = pose.position, pose.orientation
    out = np.eye(4)
    try:
        out[:3, :3] = quat_xyzw_to_matrix(float(q.x), float(q.y), float(q.z), float(q.w))
    except ShapeError as err:
        raise AdapterError(f"pose.orientation: {err}") from err
    out[:3, 3] = [float(p.x), float(p.y), float(p.z)]
    if not np.isfinite(out).all():
        raise AdapterError("pose.position: not finite")
    return out


def c2w_to_pose(c2w: np.ndarray, stamp_ns: int, frame_id: str) -> dict[str, Any]:
    """Field values of a PoseStamped holding ``c2w`` (pose of the camera optical frame in ``frame_id``)."""
    c2w = np.asarray(c2w, dtype=np.float64)
    if c2w.shape != (4, 4) or not np.isfinite(c2w).all():
        raise AdapterError(f"c2w: expected a finite 4x4 matrix, got shape {c2w.shape}")
    x, y, z, w = _matrix_to_quat_xyzw(c2w[:3, :3])
    sec, nanosec = ns_to_stamp(stamp_ns)
    return {
        "header": {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": frame_id},
        "pose": {
            "position": {"x": float(c2w[0, 3]), "y": float(c2w[1, 3]), "z": float(c2w[2, 3])},
            "orientation": {"x": x, "y": y, "z": z, "w": w},
        },
    }
