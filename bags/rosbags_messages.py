"""rosbags (typestore) messages from the adapters' field values."""

from __future__ import annotations

from typing import Any

import numpy as np
from rosbags.typesys.store import Typestore

__all__ = ["camera_info", "clock", "image", "pose_stamped"]


def _header(ts: Typestore, h: dict[str, Any]) -> Any:
    time_cls, header_cls = ts.types["builtin_interfaces/msg/Time"], ts.types["std_msgs/msg/Header"]
    return header_cls(stamp=time_cls(sec=h["stamp"]["sec"], nanosec=h["stamp"]["nanosec"]), frame_id=h["frame_id"])


def image(ts: Typestore, f: dict[str, Any]) -> Any:
    """sensor_msgs/msg/Image."""
    return ts.types["sensor_msgs/msg/Image"](
        header=_header(ts, f["header"]),
        height=f["height"],
        width=f["width"],
        encoding=f["encoding"],
        is_bigendian=f["is_bigendian"],
        step=f["step"],
        data=np.frombuffer(f["data"], dtype=np.uint8),
    )


def camera_info(ts: Typestore, f: dict[str, Any]) -> Any:
    """sensor_msgs/msg/CameraInfo."""
    roi = ts.types["sensor_msgs/msg/RegionOfInterest"](**f["roi"])
    return ts.types["sensor_msgs/msg/CameraInfo"](
        header=_header(ts, f["header"]),
        height=f["height"],
        width=f["width"],
        distortion_model=f["distortion_model"],
        d=np.asarray(f["d"], np.float64),
        k=np.asarray(f["k"], np.float64),
        r=np.asarray(f["r"], np.float64),
        p=np.asarray(f["p"], np.float64),
        binning_x=f["binning_x"],
        binning_y=f["binning_y"],
        roi=roi,
    )


def pose_stamped(ts: Typestore, f: dict[str, Any]) -> Any:
    """geometry_msgs/msg/PoseStamped."""
    p, q = f["pose"]["position"], f["pose"]["orientation"]
    pose = ts.types["geometry_msgs/msg/Pose"](
        position=ts.types["geometry_msgs/msg/Point"](**p), orientation=ts.types["geometry_msgs/msg/Quaternion"](**q)
    )
    return ts.types["geometry_msgs/msg/PoseStamped"](header=_header(ts, f["header"]), pose=pose)


def clock(ts: Typestore, sec: int, nanosec: int) -> Any:
    """rosgraph_msgs/msg/Clock."""
    return ts.types["rosgraph_msgs/msg/Clock"](clock=ts.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec))
