"""sensor_msgs/Image <-> numpy, honouring row padding (step) and the big-endian flag."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.lib.stride_tricks

from msg_adapters.errors import AdapterError
from msg_adapters.stamps import ns_to_stamp, stamp_to_ns

__all__ = [
    "ENCODINGS",
    "MAX_LABEL_ID",
    "depth_from_image",
    "image_fields",
    "image_to_numpy",
    "labels_from_image",
    "rgb_from_image",
]

# encoding -> (numpy dtype, channels)
ENCODINGS: dict[str, tuple[np.dtype, int]] = {
    "rgb8": (np.dtype(np.uint8), 3),
    "bgr8": (np.dtype(np.uint8), 3),
    "rgba8": (np.dtype(np.uint8), 4),
    "bgra8": (np.dtype(np.uint8), 4),
    "mono8": (np.dtype(np.uint8), 1),
    "8UC1": (np.dtype(np.uint8), 1),
    "mono16": (np.dtype(np.uint16), 1),
    "16UC1": (np.dtype(np.uint16), 1),
    "32FC1": (np.dtype(np.float32), 1),
    "32SC1": (np.dtype(np.int32), 1),
}
DEPTH_ENCODINGS = ("16UC1", "mono16", "32FC1")
MAX_LABEL_ID = 65535
LABEL_ENCODINGS = ("8UC1", "mono8", "16UC1", "mono16", "32SC1")


def image_to_numpy(msg: Any) -> np.ndarray:  # [H, W] or [H, W, C] in native byte order
    """Pixels of an Image message (rclpy, rosbags or mcap-ros2) as an array (zero-copy when possible)."""
    enc = str(msg.encoding)
    if enc not in ENCODINGS:
        raise AdapterError(f"encoding: {enc!r} is not supported (supported: {', '.join(ENCODINGS)})")
    dtype, ch = ENCODINGS[enc]
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    row = w * ch * dtype.itemsize
    if h <= 0 or w <= 0:
        raise AdapterError(f"height/width: image is {w}x{h}")
    if step < row:
        raise AdapterError(f"step: {step} bytes per row is less than width {w} x {ch} x {dtype.itemsize} = {row}")
    buf = np.frombuffer(msg.data, dtype=np.uint8)
    if buf.size < step * (h - 1) + row:
        raise AdapterError(f"data: {buf.size} bytes, but {w}x{h} {enc} with step {step} needs {step * (h - 1) + row}")
    dt = dtype.newbyteorder(">" if msg.is_bigendian else "<")
    rows = np.lib.stride_tricks.as_strided(buf, shape=(h, row), strides=(step, 1), writeable=False)  # skips padding
    arr = rows.view(dt).reshape((h, w, ch) if ch > 1 else (h, w))
    return arr if dt.isnative else arr.astype(dtype.newbyteorder("="))


def rgb_from_image(msg: Any) -> np.ndarray:  # [H, W, 3] uint8 RGB
    """A colour image as RGB (from rgb8, bgr8, rgba8, bgra8, mono8)."""
    arr = image_to_numpy(msg)
    enc = str(msg.encoding)
    if enc == "rgb8":
        return arr.copy()  # own the pixels: message buffers are read-only and may be reused
    if enc == "bgr8":
        return np.ascontiguousarray(arr[..., ::-1])
    if enc == "rgba8":
        return np.ascontiguousarray(arr[..., :3])
    if enc == "bgra8":
        return np.ascontiguousarray(arr[..., 2::-1])
    if enc in ("mono8", "8UC1"):
        return np.repeat(arr[..., None], 3, axis=2)
    raise AdapterError(f"encoding: {enc!r} is not a colour encoding (rgb8, bgr8, rgba8, bgra8, mono8)")


def depth_from_image(msg: Any, depth_scale: float = 1000.0) -> np.ndarray:  # [H, W] float32 metres, 0 = invalid
    """Depth in metres from a depth Image.

    16UC1/mono16 in ``depth_scale`` units per metre (1000 = millimetres), 32FC1 in metres (NaN and
    inf become 0, REP-118).
    """
    enc = str(msg.encoding)
    if enc not in DEPTH_ENCODINGS:
        raise AdapterError(f"encoding: depth must be 16UC1, mono16 or 32FC1, got {enc!r}")
    arr = image_to_numpy(msg)
    if enc == "32FC1":
        out = np.where(np.isfinite(arr) & (arr > 0), arr, 0.0).astype(np.float32)
    else:
        out = np.divide(arr, np.float32(depth_scale), dtype=np.float32)  # one pass, same values as float32 / float32
    return out


def labels_from_image(msg: Any, max_id: int = MAX_LABEL_ID) -> np.ndarray:  # [H, W] int32 class ids
    """A label image (8UC1, mono8, 16UC1, mono16, 32SC1) as class ids in ``0..max_id``.

    Ids size per-class tables downstream (decoding candidates, palettes, confusion matrices), so an
    id above ``max_id`` (default 65535, what 16-bit images and bags hold) is refused rather than
    letting a 32-bit noise image grow them without bound.
    """
    enc = str(msg.encoding)
    if enc not in LABEL_ENCODINGS:
        raise AdapterError(f"encoding: labels must be one of {', '.join(LABEL_ENCODINGS)}, got {enc!r}")
    arr = image_to_numpy(msg).astype(np.int32)
    if not arr.size:
        return arr
    limit = np.iinfo(ENCODINGS[enc][0]).max
    if enc == "32SC1" and arr.min() < 0:  # the only signed encoding
        raise AdapterError("data: label image holds negative class ids")
    if limit > max_id and arr.max() > max_id:  # only a wider encoding can exceed it: no pass otherwise
        raise AdapterError(f"data: label image holds class id {int(arr.max())} > {max_id}")
    return arr


def image_fields(arr: np.ndarray, encoding: str, stamp_ns: int, frame_id: str) -> dict[str, Any]:
    """Field values of an Image message for ``arr`` (``data`` as ``bytes``; dense rows, little endian)."""
    if encoding not in ENCODINGS:
        raise AdapterError(f"encoding: {encoding!r} is not supported")
    dtype, ch = ENCODINGS[encoding]
    arr = np.asarray(arr)
    expected_ndim = 3 if ch > 1 else 2
    if arr.ndim != expected_ndim or (ch > 1 and arr.shape[2] != ch):
        raise AdapterError(
            f"data: {encoding} needs an array of {expected_ndim} dims with {ch} channels, got {arr.shape}"
        )
    arr = np.ascontiguousarray(arr, dtype=dtype.newbyteorder("<"))
    sec, nanosec = ns_to_stamp(stamp_ns)
    return {
        "header": {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": frame_id},
        "height": int(arr.shape[0]),
        "width": int(arr.shape[1]),
        "encoding": encoding,
        "is_bigendian": 0,
        "step": int(arr.shape[1] * ch * dtype.itemsize),
        "data": arr.tobytes(),
    }


def image_stamp_ns(msg: Any) -> int:
    """Time stamp of an Image (or any message with a header) in nanoseconds."""
    return stamp_to_ns(msg.header.stamp)
