"""``camera.yaml``: width, height, fx, fy, cx, cy and optional depth_scale (units per metre)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import yaml

from sgs_slam_core.errors import DatasetError, ShapeError
from sgs_slam_core.fileio import read_yaml, write_text
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.validate import as_float, as_int

__all__ = ["CameraFile", "read_camera_file", "write_camera_file"]

_KEYS = ("width", "height", "fx", "fy", "cx", "cy")
MAX_SIDE = 16384  # px: larger than any RGB-D camera


@dataclass(frozen=True)
class CameraFile:
    """Contents of a camera file."""

    intrinsics: Intrinsics
    depth_scale: float | None = None


def read_camera_file(path: Path) -> CameraFile:
    """Parse and validate a camera file."""
    data = read_yaml(path, "camera file")
    if not isinstance(data, dict):
        raise DatasetError(f"camera file {path} must be a mapping with {', '.join(_KEYS)}")
    missing = [k for k in _KEYS if k not in data]
    unknown = sorted(set(data) - {*_KEYS, "depth_scale"})
    if missing or unknown:
        raise DatasetError(f"camera file {path}: missing {missing}, unknown {unknown}")
    side = {k: as_int(data[k], f"camera file {path}: {k}", DatasetError, 1, MAX_SIDE) for k in ("width", "height")}
    num = {k: as_float(data[k], f"camera file {path}: {k}", DatasetError) for k in ("fx", "fy", "cx", "cy")}
    scale = data.get("depth_scale")
    if scale is not None:
        scale = as_float(scale, f"camera file {path}: depth_scale", DatasetError, 0.0, lo_open=True)
    try:
        k = Intrinsics(num["fx"], num["fy"], num["cx"], num["cy"], side["width"], side["height"])
    except ShapeError as err:
        raise DatasetError(f"camera file {path}: {err}") from err
    return CameraFile(k, scale)


def write_camera_file(path: Path, intrinsics: Intrinsics, depth_scale: float | None = None) -> None:
    """Write a camera file."""
    data = {
        "width": intrinsics.width,
        "height": intrinsics.height,
        "fx": intrinsics.fx,
        "fy": intrinsics.fy,
        "cx": intrinsics.cx,
        "cy": intrinsics.cy,
    }
    if depth_scale is not None:
        data["depth_scale"] = depth_scale
    write_text(path, yaml.safe_dump(data, sort_keys=False))
