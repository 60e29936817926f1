"""The tracker interface: one frame's pose against a fixed map."""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import numpy as np
from torch import Tensor

from sgs_slam_core.frame_data import FrameTensors
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.slam.features import Landmarks
from sgs_slam_core.slam.tracker import TrackResult

__all__ = ["Tracker"]


class Tracker(Protocol):
    """Estimates a frame's world-to-camera pose against a map that it does not change."""

    def track(
        self,
        gaussians: GaussianMap,
        frame: FrameTensors,
        init_w2c: np.ndarray | Tensor,  # [4, 4] float64, the motion model's start (a Tensor: on the device)
        use_semantics: bool,
        newer_frame_waiting: Callable[[], bool] | None = None,
        landmarks: Landmarks | None = None,
        also_read: Tensor | None = None,  # [K] on the device
    ) -> TrackResult:
        """The pose of ``frame`` and how tracking went.

        ``newer_frame_waiting`` (live): once it returns True the tracker ends as soon as it may.
        ``landmarks``: map points the frame's features see, which a tracker may hold the pose to.
        ``also_read``: values the caller needs on the host, read back with the pose (in
        ``TrackResult.also_read``), so a start left on the device costs no read of its own.
        """
        ...
