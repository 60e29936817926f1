"""The paper's tracker: Adam steps on the rendering loss (SplaTAM, SGS-SLAM)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np
from torch import Tensor

from sgs_slam_core.config.sections import TrackingSettings
from sgs_slam_core.frame_data import FrameTensors
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.kernels.base import Kernels
from sgs_slam_core.slam.features import Landmarks
from sgs_slam_core.slam.pose import read_pose
from sgs_slam_core.slam.tracker import TrackResult, track

__all__ = ["AdamTracker"]


class AdamTracker:
    """Every step renders the map and back-propagates the L1 depth/colour/semantic loss to the pose.

    Faithful to the paper (its loss, mask and rates); ``tracking.adam.iterations`` steps at most, fewer
    with early stopping.
    """

    def __init__(self, settings: TrackingSettings, kernels: Kernels) -> None:
        self.settings, self.kernels = settings, kernels

    def track(
        self,
        gaussians: GaussianMap,
        frame: FrameTensors,
        init_w2c: np.ndarray | Tensor,  # [4, 4] float64
        use_semantics: bool,
        newer_frame_waiting: Callable[[], bool] | None = None,
        landmarks: Landmarks | None = None,
        also_read: Tensor | None = None,  # [K]
    ) -> TrackResult:
        """Adam from ``init_w2c``, keeping the best evaluated pose (one render per step).

        ``landmarks`` are not used: the paper's tracker optimises the rendering loss alone. A start on
        the device is read back first, with ``also_read``: every step's stop test reads anyway.
        """
        init, read = read_pose(init_w2c, also_read)
        result = track(gaussians, frame, init, self.settings, self.kernels, use_semantics, newer_frame_waiting)
        return replace(result, renders=result.iterations, also_read=read)
