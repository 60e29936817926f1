"""The config preset a converted bag was made for, stored in its rosbag2 ``custom_data``.

``sgs-slam-bag convert`` records the preset its dataset folder would get (``synthetic`` for our
scenes, ``replica``, ``scannet``, ``tum``), so ``sgs-slam run BAG`` picks the same one as
``sgs-slam run FOLDER``. This module is the only reader and writer of that key.
"""

from __future__ import annotations

from pathlib import Path

from bags.errors import BagError
from bags.reader import read_custom_data
from sgs_slam_core.config import list_presets

__all__ = ["PRESET_KEY", "preset_metadata", "read_bag_preset"]

PRESET_KEY = "sgs_slam_preset"


def preset_metadata(preset: str) -> dict[str, str]:
    """The ``custom_data`` entries recording ``preset`` (validated against the built-in presets)."""
    if preset not in list_presets():
        raise BagError(f"unknown preset {preset!r}; choose one of {', '.join(list_presets())}")
    return {PRESET_KEY: preset}


def read_bag_preset(path: Path) -> str | None:
    """The preset stored in a bag's metadata; None for bags without one (recorded elsewhere, older)."""
    preset = read_custom_data(path).get(PRESET_KEY)
    if preset is None:
        return None
    if preset not in list_presets():
        raise BagError(
            f"{path}: its metadata names preset {preset!r}, which this version does not have "
            f"(choose one with --preset: {', '.join(list_presets())})"
        )
    return preset
