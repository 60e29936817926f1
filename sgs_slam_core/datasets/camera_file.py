"""``camera.yaml``: width, height, fx, fy, cx, cy and optional depth_scale (units per metre)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import yaml

from sgs_slam_core.errors import DatasetError, ShapeError
from sgs_slam_core.geometry.camera import Intrinsics

__all__ = ["CameraFile", "read_camera_file", "write_camera_file"]

_KEYS = ("width", "height", "fx", "fy", "cx", "cy")


@dataclass(frozen=True)
class CameraFile:
    """Contents of a camera file."""

    intrinsics: Intrinsics
    depth_scale: float | None = None


def read_camera_file(path: Path) -> CameraFile:
    """Parse and validate a camera file."""
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as err:
        raise DatasetError(f"cannot read camera file {path}: {err}") from err
    if not isinstance(data, dict):
        raise DatasetError(f"camera file {path} must be a mapping with {', '.join(_KEYS)}")
    missing = [k for k in _KEYS if k not in data]
    unknown = sorted(set(data) - {*_KEYS, "depth_scale"})
    if missing or unknown:
        raise DatasetError(f"camera file {path}: missing {missing}, unknown {unknown}")
    try:
        k = Intrinsics(
            float(data["fx"]), float(data["fy"]), float(data["cx"]), float(data["cy"]),
            int(data["width"]), int(data["height"]),
        )  # fmt: skip
        scale = float(data["depth_scale"]) if data.get("depth_scale") is not None else None
    except (TypeError, ValueError, ShapeError) as err:
        raise DatasetError(f"camera file {path}: {err}") from err
    if scale is not None and not scale > 0:
        raise DatasetError(f"camera file {path}: depth_scale must be > 0, got {scale}")
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
    path.write_text(yaml.safe_dump(data, sort_keys=False))
