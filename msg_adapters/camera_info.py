"""sensor_msgs/CameraInfo <-> Intrinsics."""

from __future__ import annotations

from typing import Any

import numpy as np

from msg_adapters.errors import AdapterError
from msg_adapters.stamps import ns_to_stamp
from sgs_slam_core.errors import ShapeError
from sgs_slam_core.geometry.camera import Intrinsics

__all__ = ["camera_info_fields", "camera_info_to_intrinsics"]


def camera_info_to_intrinsics(msg: Any) -> tuple[Intrinsics, list[str]]:
    """Intrinsics from the K matrix, plus warnings.

    A warning is given e.g. for non-zero distortion: tracking assumes rectified images, so distorted
    input should go through image_proc first.
    """
    k = np.asarray(msg.k, dtype=np.float64).reshape(-1)
    if k.size != 9:
        raise AdapterError(f"k: expected 9 values, got {k.size}")
    try:
        intr = Intrinsics(float(k[0]), float(k[4]), float(k[2]), float(k[5]), int(msg.width), int(msg.height))
    except ShapeError as err:
        raise AdapterError(f"k/width/height: {err}") from err
    warnings = []
    d = np.asarray(msg.d, dtype=np.float64).reshape(-1)
    if d.size and np.any(np.abs(d) > 1e-9):
        warnings.append(
            f"distortion_model {msg.distortion_model!r} with non-zero coefficients {np.round(d, 4).tolist()}: "
            "tracking assumes rectified images (use image_proc's rectify)"
        )
    return intr, warnings


def camera_info_fields(k: Intrinsics, stamp_ns: int, frame_id: str) -> dict[str, Any]:
    """Field values of a CameraInfo for undistorted (rectified) images."""
    sec, nanosec = ns_to_stamp(stamp_ns)
    kk = [k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0]
    return {
        "header": {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": frame_id},
        "height": k.height,
        "width": k.width,
        "distortion_model": "plumb_bob",
        "d": [0.0] * 5,
        "k": kk,
        "r": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        "p": [k.fx, 0.0, k.cx, 0.0, 0.0, k.fy, k.cy, 0.0, 0.0, 0.0, 1.0, 0.0],
        "binning_x": 0,
        "binning_y": 0,
        "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0, "do_rectify": False},
    }
