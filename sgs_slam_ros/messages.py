"""rclpy messages from the adapters' field values (``msg_adapters`` stays free of rclpy)."""

from __future__ import annotations

from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path
from sensor_msgs.msg import CameraInfo, Image, PointCloud2, PointField
from std_msgs.msg import Header

from msg_adapters import c2w_to_pose, camera_info_fields, image_fields, pointcloud_fields
from msg_adapters.stamps import ns_to_stamp
from sgs_slam_core.geometry.camera import Intrinsics

__all__ = ["camera_info_msg", "header", "image_msg", "path_msg", "pointcloud_msg", "pose_msg"]


def header(stamp_ns: int, frame_id: str) -> Header:
    """A Header with a nanosecond stamp."""
    sec, nanosec = ns_to_stamp(stamp_ns)
    return Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id=frame_id)


def _header_from(fields: dict[str, Any]) -> Header:
    h = fields["header"]
    return Header(stamp=Time(sec=h["stamp"]["sec"], nanosec=h["stamp"]["nanosec"]), frame_id=h["frame_id"])


def image_msg(arr: np.ndarray, encoding: str, stamp_ns: int, frame_id: str) -> Image:
    """An Image (``data`` assigned as bytes: fast)."""
    f = image_fields(arr, encoding, stamp_ns, frame_id)
    return Image(
        header=_header_from(f),
        height=f["height"],
        width=f["width"],
        encoding=f["encoding"],
        is_bigendian=f["is_bigendian"],
        step=f["step"],
        data=f["data"],
    )


def camera_info_msg(k: Intrinsics, stamp_ns: int, frame_id: str) -> CameraInfo:
    """CameraInfo of rectified images with intrinsics ``k``."""
    f = camera_info_fields(k, stamp_ns, frame_id)
    msg = CameraInfo(
        header=_header_from(f), height=f["height"], width=f["width"], distortion_model=f["distortion_model"]
    )
    msg.d, msg.k, msg.r, msg.p = f["d"], f["k"], f["r"], f["p"]
    return msg


def pose_msg(c2w: np.ndarray, stamp_ns: int, frame_id: str) -> PoseStamped:
    """PoseStamped of a camera-to-world matrix."""
    f = c2w_to_pose(c2w, stamp_ns, frame_id)
    msg = PoseStamped(header=_header_from(f))
    p, q = f["pose"]["position"], f["pose"]["orientation"]
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = p["x"], p["y"], p["z"]
    msg.pose.orientation.x, msg.pose.orientation.y = q["x"], q["y"]
    msg.pose.orientation.z, msg.pose.orientation.w = q["z"], q["w"]
    return msg


def path_msg(poses: list[PoseStamped], stamp_ns: int, frame_id: str) -> Path:
    """A Path of already-built poses."""
    return Path(header=header(stamp_ns, frame_id), poses=poses)


def pointcloud_msg(points: np.ndarray, stamp_ns: int, frame_id: str) -> PointCloud2:
    """An unorganised PointCloud2 of a structured array."""
    f = pointcloud_fields(points, stamp_ns, frame_id)
    return PointCloud2(
        header=_header_from(f),
        height=f["height"],
        width=f["width"],
        fields=[
            PointField(name=p["name"], offset=p["offset"], datatype=p["datatype"], count=p["count"])
            for p in f["fields"]
        ],
        is_bigendian=f["is_bigendian"],
        point_step=f["point_step"],
        row_step=f["row_step"],
        data=f["data"],
        is_dense=f["is_dense"],
    )
