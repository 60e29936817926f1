"""The map frame: where the first camera of a run sits, by the ``map_frame`` settings (e.g. levelled on the floor)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sgs_slam_core.config.sections import MapFrameSettings
from sgs_slam_core.frame import Frame
from sgs_slam_core.geometry.gravity import FloorPlane, FloorSettings, MapAlignment, initial_map_pose, pose_from_xyz_rpy

__all__ = ["MapFrameChoice", "MapFramePolicy"]


@dataclass(frozen=True)
class MapFrameChoice:
    """The first camera pose of a run and how it was chosen."""

    c2w: np.ndarray  # [4, 4] the first camera in the map frame
    alignment: str  # as used: "optical", "mount", "floor", "mount (no floor in the first frame)" or "given"
    floor: FloorPlane | None = None  # the plane the map was levelled on


class MapFramePolicy:
    """Chooses the first pose of an empty map from the first frame."""

    def __init__(self, settings: MapFrameSettings) -> None:
        self.alignment = MapAlignment(settings.alignment)
        self.mount = pose_from_xyz_rpy(settings.camera_mount)  # [4, 4] camera optical frame in the body frame
        self.floor = FloorSettings(max_tilt_deg=settings.floor_max_tilt_deg)

    def choose(self, frame: Frame) -> MapFrameChoice:
        """The first camera pose for ``frame`` (its depth finds the floor)."""
        pose, plane = initial_map_pose(self.alignment, frame.depth, frame.intrinsics, self.mount, self.floor)
        used = self.alignment.value
        if self.alignment is MapAlignment.FLOOR and plane is None:
            used = f"{MapAlignment.MOUNT.value} (no floor in the first frame)"
        return MapFrameChoice(pose, used, plane)
