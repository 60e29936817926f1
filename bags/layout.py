"""Topic names of the bags we write (names users know from realsense-ros)."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["BagTopics"]


@dataclass(frozen=True)
class BagTopics:
    """Where each stream lives in a bag (override for bags recorded elsewhere)."""

    color: str = "/camera/color/image_raw"
    camera_info: str = "/camera/color/camera_info"
    depth: str = "/camera/depth/image_raw"
    semantic: str = "/camera/semantic/image_raw"
    pose: str = "/camera/pose"
    clock: str = "/clock"
