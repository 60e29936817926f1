"""Where a frame was taken: tracked from the motion model's start and judged, or found again while lost.

The tracker (any of them) refines a start; the guard judges the result, the frame's own features
included; a failed frame is tried once more, and then takes the pose its features give. While
the camera is lost, each frame is tried from the poses the keyframes' features give instead.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from sgs_slam_core.config.schema import SlamConfig
from sgs_slam_core.frame import Frame
from sgs_slam_core.frame_data import FrameTensors
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.geometry.se3 import se3_inverse
from sgs_slam_core.kernels.base import Kernels
from sgs_slam_core.slam.feature_odometry import FeatureView
from sgs_slam_core.slam.features import Landmarks
from sgs_slam_core.slam.guard import FeatureEvidence, TrackingGuard, TrackingState
from sgs_slam_core.slam.keyframe_store import KeyframeStore
from sgs_slam_core.slam.motion import MotionModel
from sgs_slam_core.slam.relocalization import Relocalizer
from sgs_slam_core.slam.tracker import TrackResult, judge_pose
from sgs_slam_core.slam.trackers import Tracker

__all__ = ["Localization", "Localizer"]

# A lost frame is tracked from at most this many candidate poses: the keyframes whose features match
# it best (and the last accepted frame's), each solved by PnP first; each one costs a tracking.
RELOCALIZE_CANDIDATES = 3


@dataclass(frozen=True)
class Localization:
    """A frame's pose as tracking found it, why the guard rejected it (if it did), and the tracking state."""

    result: TrackResult | None  # None: lost, and no candidate was tried
    failure: str | None
    state: TrackingState


def _combined(first: TrackResult, second: TrackResult) -> TrackResult:
    """``second`` with the iterations, renders and time of both tracking attempts."""
    renders = (first.renders or first.iterations) + (second.renders or second.iterations)
    spent = {"iterations": first.iterations + second.iterations, "renders": renders}
    return replace(second, time_s=first.time_s + second.time_s, **spent)


class Localizer:
    """Runs the tracker from the starts the motion model and the features give, and lets the guard judge.

    Shares the run's motion model, tracker and guard with :class:`~sgs_slam_core.slam.system.Slam`;
    holds the keyframes' features for relocalization.
    """

    def __init__(
        self, config: SlamConfig, motion: MotionModel, tracker: Tracker, guard: TrackingGuard, kernels: Kernels
    ) -> None:
        self.config, self.motion, self.tracker, self.guard, self.kernels = config, motion, tracker, guard, kernels
        c = config
        relocalizes = c.features.enabled and c.guard.lost_after > 0
        self.relocalizer = (
            Relocalizer(c.features, RELOCALIZE_CANDIDATES, c.guard.relocalize_min_inliers) if relocalizes else None
        )

    def locate(
        self,
        gaussians: GaussianMap,
        keyframes: KeyframeStore,
        frame: Frame,
        data: FrameTensors,
        view: FeatureView | None,
        newer_frame_waiting: Callable[[], bool] | None = None,
    ) -> Localization:
        """The frame tracked against ``gaussians``, or relocalized against ``keyframes`` while lost."""
        use_sem = frame.labels is not None and self.config.tracking.weight_semantic > 0
        if self.guard.lost:
            return self._relocalized(gaussians, keyframes, data, view, use_sem)
        return self._tracked(gaussians, frame, data, view, use_sem, newer_frame_waiting)

    # ------------------------------------------------------------------ tracking
    def _tracked(
        self,
        gaussians: GaussianMap,
        frame: Frame,
        data: FrameTensors,
        view: FeatureView | None,
        use_sem: bool,
        newer_frame_waiting: Callable[[], bool] | None,
    ) -> Localization:
        """The frame tracked from the motion model's start, judged by the guard (retried once when it fails).

        A frame that still fails takes the pose its features give against the last accepted frame,
        where they give one with ``guard.relocalize_min_inliers``: judged as a tracked pose would
        be, it is accepted (and mapped) if it passes; otherwise the frame fails with it (not
        mapped), but the camera is not lost. After ``guard.max_feature_frames`` frames in a row
        placed so, a failed frame fails as one without features would.
        """
        start = self.motion.start(frame.stamp_ns, data, view)
        w2c = np.linalg.inv(start.c2w) if isinstance(start.c2w, np.ndarray) else se3_inverse(start.c2w)
        landmarks = self._landmarks(view)
        result = self.tracker.track(gaussians, data, w2c, use_sem, newer_frame_waiting, landmarks, start.icp_outcome)
        self.motion.settle(result.also_read)
        failure = self.guard.check(*self._evidence(result, view))
        if failure is not None and self.config.guard.retry:
            second = view.c2w if view is not None and view.c2w is not None and not start.from_features else None
            result, failure = self._retried(gaussians, data, second, use_sem, result, failure, view)
        located = failure is not None and view is not None and view.inliers >= self.config.guard.relocalize_min_inliers
        on_features = False
        if located and not self.guard.trusts_features:
            located, failure = False, f"{failure}; the features alone placed too many frames in a row"
        elif located:
            result, failure = self._feature_pose(gaussians, data, view, use_sem, result, failure)
            on_features = failure is None
        return Localization(result, failure, self.guard.settle(failure is not None, located, on_features))

    def _retried(
        self,
        gaussians: GaussianMap,
        data: FrameTensors,
        start: np.ndarray | None,
        use_sem: bool,
        failed: TrackResult,
        failure: str,
        view: FeatureView | None,
    ) -> tuple[TrackResult, str | None]:
        """A failed frame tracked again from ``start`` (c2w), else the motion model's fallback start.

        The first result is kept if that fails too.
        """
        start = start if start is not None else self.motion.fallback(data)
        if start is None:
            return failed, failure
        result = self.tracker.track(gaussians, data, np.linalg.inv(start), use_sem, None, self._landmarks(view))
        evidence = self._evidence(result, view)
        if self.guard.judge(*evidence) is not None:
            return failed, failure
        self.guard.accept(evidence[0], evidence[1])
        return _combined(failed, result), None

    def _feature_pose(
        self,
        gaussians: GaussianMap,
        data: FrameTensors,
        view: FeatureView,
        use_sem: bool,
        failed: TrackResult,
        failure: str,
    ) -> tuple[TrackResult, str | None]:
        """The features' pose of a frame tracking could not place, judged at its rendering."""
        w2c = np.linalg.inv(view.c2w)
        judged = judge_pose(gaussians, data, w2c, self.config.tracking, self.kernels, use_sem)
        result = _combined(failed, judged)
        reason = self.guard.judge(judged.depth_residual_m, judged.loss_per_pixel, judged.valid_fraction)
        if reason is not None:
            return replace(result, rendering=None), f"{failure}; the features' pose kept ({reason})"
        self.guard.accept(judged.depth_residual_m, judged.loss_per_pixel)
        return result, None

    def _landmarks(self, view: FeatureView | None) -> Landmarks | None:
        """The inlier matches of the frame's feature pose, as landmarks for the tracker (None without one)."""
        return None if view is None else view.landmarks(self.config.features.reprojection_px)

    def _evidence(
        self, result: TrackResult, view: FeatureView | None
    ) -> tuple[float, float, float, FeatureEvidence | None]:
        """What the guard judges a tracked pose by: residual, loss per pixel, mapped fraction, the features' say."""
        features = None
        if view is not None and np.isfinite(result.depth_residual_m):
            features = view.evidence(np.linalg.inv(result.w2c), self.config.features.reprojection_px)
        return result.depth_residual_m, result.loss_per_pixel, result.valid_fraction, features

    # ------------------------------------------------------------------ relocalization
    def _relocalized(
        self,
        gaussians: GaussianMap,
        keyframes: KeyframeStore,
        data: FrameTensors,
        view: FeatureView | None,
        use_sem: bool,
    ) -> Localization:
        """While lost: the frame tracked from each candidate the features give, the first the guard accepts.

        Candidates: the pose against the last accepted frame, then the keyframes that match best
        (``RELOCALIZE_CANDIDATES`` in all), each judged against its own feature matches.
        """
        candidates = [] if view is None else self._candidates(keyframes, view)
        tried: TrackResult | None = None
        for candidate in candidates[:RELOCALIZE_CANDIDATES]:
            start = self._candidate_start(keyframes, candidate, data)
            landmarks = self._landmarks(candidate)
            result = self.tracker.track(gaussians, data, np.linalg.inv(start), use_sem, None, landmarks)
            tried = result if tried is None else _combined(tried, result)
            evidence = self._evidence(result, candidate)
            if self.guard.judge(*evidence) is None:
                self.guard.accept(evidence[0], evidence[1])
                found = replace(tried, w2c=result.w2c, rendering=result.rendering)
                return Localization(found, None, self.guard.relocalized())
        reason = (
            f"lost: none of {len(candidates)} feature candidates passed" if candidates else "lost: no feature match"
        )
        return Localization(tried, reason, self.guard.settle(True))

    def _candidates(self, keyframes: KeyframeStore, view: FeatureView) -> list[FeatureView]:
        """The lost frame's feature poses: against the last accepted frame, then the keyframes, best first."""
        s = self.config.guard
        found = [view] if view.c2w is not None and view.inliers >= s.relocalize_min_inliers else []
        if self.relocalizer is not None:
            found += self.relocalizer.candidates(keyframes, view)
        return found

    def _candidate_start(self, keyframes: KeyframeStore, candidate: FeatureView, data: FrameTensors) -> np.ndarray:
        """A candidate's feature pose (c2w [4, 4]) refined by the depth ICP against the frame whose features gave it."""
        index = None if candidate.reference is None else candidate.reference.index
        if index is None:  # the last accepted frame's features: the motion ICP's reference frame
            return self.motion.refine(data, candidate.c2w)
        keyframe = keyframes.find(index)
        return candidate.c2w if keyframe is None else self.motion.refine(data, candidate.c2w, keyframe)
