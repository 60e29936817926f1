"""Where tracking starts: constant velocity, the features' pose where the two disagree, refined by depth ICP.

Only accepted poses count; a rejected frame is tracked again from the fallback start.
"""

from __future__ import annotations

from collections import deque
from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor

from sgs_slam_core.config.sections import FeatureSettings, MotionSettings
from sgs_slam_core.frame import CompactFrame, Frame
from sgs_slam_core.frame_data import FrameTensors
from sgs_slam_core.geometry.icp import IcpKernels
from sgs_slam_core.slam.feature_odometry import FeatureOdometry, FeatureView
from sgs_slam_core.slam.icp_init import IcpInit, ReferencePolicy
from sgs_slam_core.slam.pose import predict_constant_velocity, read_pose

__all__ = ["MotionModel", "Start"]

# The ICP result is used only when at least this fraction of the frame's pixels with depth find a
# correspondence; otherwise the prediction is kept.
ICP_MIN_INLIERS = 0.3
# The constant-velocity guess stays the start while it explains at least this share of the feature
# pose's inlier matches (each within twice ``features.reprojection_px``); otherwise the feature pose
# replaces it. A guess that explains them is as good a start, and tracking refines either.
START_AGREEMENT = 0.8


class Start(NamedTuple):
    """A frame's starting pose and where it came from."""

    c2w: np.ndarray | Tensor  # [4, 4] float64; the ICP's start stays on the frame's device, not read back
    from_features: bool  # the feature pose replaced the constant-velocity guess
    icp_outcome: Tensor | None = None  # [3] float64 where the ICP ran: for :meth:`MotionModel.settle`, once read


class MotionModel:
    """The motion prior of one run: the poses it has seen, the frame interval, the ICP and feature references."""

    def __init__(
        self,
        settings: MotionSettings,
        initial_c2w: np.ndarray,
        icp_kernels: IcpKernels | None = None,
        features: FeatureSettings | None = None,
    ) -> None:
        """``icp_kernels``: the ICP's compiled parts (``Kernels.icp``); None = ``geometry.icp``'s PyTorch code.

        ``features``: the feature start's settings (None or disabled: no feature start).
        """
        self.settings = settings
        self.features = None if features is None or not features.enabled else FeatureOdometry(features)
        self.initial_c2w = initial_c2w
        self._history: deque[tuple[int, np.ndarray]] = deque(maxlen=2)  # (stamp_ns, c2w) of this run
        self._resumed: list[np.ndarray] = []  # last two c2w of a loaded map: it goes on moving
        self._min_interval_ns: int | None = None  # shortest stamp gap between two tracked frames
        icp = settings.icp
        policy = ReferencePolicy(settings.icp_reference_distance_m, settings.icp_reference_angle_deg)
        self._icp = None if icp is None else IcpInit(icp, ICP_MIN_INLIERS, icp_kernels, policy)

    def resume(self, poses: list[np.ndarray]) -> None:
        """Continue from a saved run's last poses (c2w [4, 4], oldest first)."""
        self._resumed = [np.asarray(p, dtype=np.float64).copy() for p in poses[-2:]]

    def view(self, frame: Frame) -> FeatureView | None:
        """``frame``'s features and the pose they give it against the last accepted frame (None: off)."""
        return None if self.features is None else self.features.view(frame)

    @property
    def last_c2w(self) -> np.ndarray:  # [4, 4]
        """The last accepted pose (a resumed map's last, or the initial pose before any)."""
        poses = [*self._resumed, *(c2w for _, c2w in self._history)]
        return (poses[-1] if poses else self.initial_c2w).copy()

    def predict(self, stamp_ns: int, data: FrameTensors, view: FeatureView | None = None) -> np.ndarray:  # c2w [4, 4]
        """The starting pose of a frame taken at ``stamp_ns``: :meth:`start`'s, read back and settled."""
        start = self.start(stamp_ns, data, view)
        c2w, outcome = read_pose(start.c2w, start.icp_outcome)
        self.settle(outcome)
        return c2w

    def start(self, stamp_ns: int, data: FrameTensors, view: FeatureView | None = None) -> Start:
        """The starting pose of a frame taken at ``stamp_ns``; ``data`` is its depth for the ICP.

        ``view`` (:meth:`view` of the frame): its feature pose replaces the constant-velocity guess
        where the guess explains fewer of its inlier matches than ``START_AGREEMENT``. Where the ICP
        refines the pose, it stays on the device; the caller reads it with the tracked pose and
        hands the ICP's outcome to :meth:`settle`.
        """
        poses = [*self._resumed, *(c2w for _, c2w in self._history)]
        prev = poses[-1] if poses else self.initial_c2w
        prev2 = poses[-2] if len(poses) > 1 and self.settings.constant_velocity else None
        c2w = predict_constant_velocity(prev, prev2, self._motion_fraction(stamp_ns))
        from_features = view is not None and view.c2w is not None and self._disagree(c2w, view)
        if from_features:
            c2w = view.c2w
        if self._icp is not None and self._intervals_since_last(stamp_ns) >= self.settings.icp_min_gap:
            refined = self._icp.start(_measured_depth(data), data.intrinsics, c2w)
            if refined is not None:
                return Start(refined.c2w, from_features, refined.outcome)
        return Start(c2w, from_features)

    def settle(self, icp_outcome: np.ndarray | None) -> None:  # [3] (Start.icp_outcome, read back)
        """The ICP's outcome for a :meth:`start`, read back: a reference it failed against is replaced."""
        if self._icp is not None and icp_outcome is not None:
            self._icp.settle(bool(icp_outcome[0] > 0))

    def fallback(self, data: FrameTensors) -> np.ndarray | None:  # c2w [4, 4]
        """A second start for a frame whose tracking failed; None before any pose.

        The last accepted pose without motion, refined by the ICP against the last accepted frame
        when the ICP is on.
        """
        if not self._history:
            return None
        c2w = self._history[-1][1].copy()
        if self._icp is not None:
            c2w, _ = self._icp.refine(_measured_depth(data), data.intrinsics, c2w)
        return c2w

    def refine(self, data: FrameTensors, c2w: np.ndarray, keyframe: CompactFrame | None = None) -> np.ndarray:
        """``c2w`` [4, 4] refined by the depth ICP against ``keyframe``, or else the ICP's reference frame.

        Unchanged when the ICP is off or finds too few correspondences (a relocalization's candidate
        pose, from the features of ``keyframe`` or of the last accepted frame).
        """
        if self._icp is None:
            return c2w
        if keyframe is None:
            return self._icp.refine(_measured_depth(data), data.intrinsics, c2w)[0]
        return self._icp.refine_against(keyframe, _measured_depth(data), data.intrinsics, c2w)[0]

    def _disagree(self, guess: np.ndarray, view: FeatureView) -> bool:  # guess: c2w [4, 4]
        """Whether the guess explains too few of the feature pose's inlier matches to stay the start."""
        s = self.features.settings if self.features is not None else None
        if s is None:
            return False
        explained = view.agreement(guess, s.reprojection_px)
        return explained is not None and explained < START_AGREEMENT

    def observe(
        self, stamp_ns: int, c2w: np.ndarray, data: FrameTensors | None, view: FeatureView | None = None
    ) -> None:
        """A frame's pose; ``data`` and ``view`` (a tracked frame the guard accepted) become the next references."""
        if self._history and stamp_ns > self._history[-1][0]:
            gap = stamp_ns - self._history[-1][0]
            self._min_interval_ns = gap if self._min_interval_ns is None else min(gap, self._min_interval_ns)
        if self._icp is not None and data is not None:
            self._icp.remember(_measured_depth(data), data.intrinsics, c2w)
        if self.features is not None and view is not None:
            self.features.accept(view, c2w)
        self._history.append((stamp_ns, c2w))

    def restart(self, stamp_ns: int, c2w: np.ndarray, data: FrameTensors | None, view: FeatureView | None) -> None:
        """Go on from a relocalized pose: no velocity across the time the camera was lost."""
        self._history.clear()
        self._resumed = []
        self.observe(stamp_ns, c2w, data, view)

    @property
    def uses_icp(self) -> bool:
        """True when accepted frames must be kept as the ICP's reference."""
        return self._icp is not None

    def _intervals_since_last(self, stamp_ns: int) -> float:
        """Camera frame intervals since the last pose: about 1 when none was dropped, 0 when unknown."""
        if not self._history or self._min_interval_ns is None:
            return 0.0
        return (stamp_ns - self._history[-1][0]) / self._min_interval_ns

    def _motion_fraction(self, stamp_ns: int) -> float:
        """Time since the last pose over the gap before it, when frames were skipped (live mode).

        1 when frames came evenly (within a camera's stamp jitter) or stamps are unknown, so lockstep
        runs repeat the last motion exactly as the reference does.
        """
        if len(self._history) < 2:
            return 1.0
        (t_prev2, _), (t_prev, _) = self._history
        last_gap, gap = t_prev - t_prev2, stamp_ns - t_prev
        if last_gap <= 0 or gap <= 0:
            return 1.0
        fraction = gap / last_gap
        return 1.0 if 2 / 3 < fraction < 1.5 else min(fraction, 4.0)


def _measured_depth(data: FrameTensors) -> torch.Tensor:  # [H, W] m
    """The frame's depth with ignored (edit-locked) pixels set to 0, as the ICP reads it."""
    return torch.where(data.valid, data.depth, 0.0)
