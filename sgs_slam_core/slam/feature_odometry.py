"""Frame-to-frame feature odometry: where the features put a new frame, given the last accepted one.

The motion model keeps the last accepted frame's features as the reference (as it keeps its depth
for the ICP); each new frame's features are matched against them and solved by PnP. That pose
does not depend on the map, so it serves three ways: as a start whose basin is as wide as the
features' (tracking from a constant-velocity guess fails when the camera swings), as landmarks the
tracker holds its pose to where the geometry leaves it free, and as evidence the guard checks a
tracked pose against (a map dragged along with a wrong pose still renders consistently).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sgs_slam_core.config.sections import FeatureSettings
from sgs_slam_core.frame import Frame
from sgs_slam_core.geometry.se3 import rotation_angle_deg
from sgs_slam_core.profiling import stage
from sgs_slam_core.slam.features import (
    MAX_DISTANCE,
    FeatureMotion,
    FrameFeatures,
    Landmarks,
    Matches,
    agreement,
    extract_features,
    inlier_landmarks,
    match_features,
    solve_motion,
)
from sgs_slam_core.slam.guard import FeatureEvidence

__all__ = ["AGREEMENT_SLACK", "FeatureOdometry", "FeatureReference", "FeatureView"]

# a tracked pose explains a match when it projects within this many times the RANSAC threshold:
# the dense solve fits every pixel, not the keypoints, so it may sit a pixel or two off them
AGREEMENT_SLACK = 2.0


@dataclass(frozen=True)
class FeatureReference:
    """Features of a frame whose pose is known: the last accepted frame, or a keyframe."""

    features: FrameFeatures
    c2w: np.ndarray  # [4, 4] float64, the pose of the frame the features came from
    index: int | None = None  # its frame index (keyframes), None for the last accepted frame


@dataclass(frozen=True)
class FeatureView:
    """One frame's features and, when a reference agreed, the pose they give it."""

    features: FrameFeatures
    reference: FeatureReference | None = None
    matches: Matches | None = None
    motion: FeatureMotion | None = None  # None: no reference, or too few matches agreed

    @property
    def c2w(self) -> np.ndarray | None:  # [4, 4]
        """The frame's camera-to-world pose by the features (None without a solved motion)."""
        if self.motion is None or self.reference is None:
            return None
        return self.reference.c2w @ np.linalg.inv(self.motion.ref_to_query)

    @property
    def inliers(self) -> int:
        """Matches that agree with the feature pose (0 without one)."""
        return 0 if self.motion is None else self.motion.inliers

    def agreement(self, c2w: np.ndarray, threshold_px: float) -> float | None:  # c2w [4, 4]
        """The share of the feature pose's inliers that ``c2w`` explains too.

        Explains: projects within ``AGREEMENT_SLACK`` times ``threshold_px`` (the RANSAC's
        threshold). None without a feature pose: nothing to check against. 1 means ``c2w`` agrees
        with the frames as well as the feature pose does.
        """
        if self.motion is None or self.reference is None or self.matches is None:
            return None
        ref_to_query = np.linalg.inv(c2w) @ self.reference.c2w
        slack = AGREEMENT_SLACK * threshold_px
        explained = agreement(self.reference.features, self.features, self.matches, ref_to_query, slack)
        return min(explained / max(self.motion.inliers, 1), 1.0)

    def evidence(self, c2w: np.ndarray, threshold_px: float) -> FeatureEvidence | None:  # c2w [4, 4]
        """What the feature pose says of ``c2w``: :meth:`agreement`, inliers, and the turn between them."""
        explained, own = self.agreement(c2w, threshold_px), self.c2w
        if explained is None or own is None:
            return None
        turn = float(rotation_angle_deg(own[:3, :3].T @ c2w[:3, :3]))
        return FeatureEvidence(explained, self.inliers, turn)

    def landmarks(self, threshold_px: float) -> Landmarks | None:
        """The feature pose's inlier matches (within ``threshold_px``) as map-frame landmarks; None without one."""
        if self.motion is None or self.reference is None or self.matches is None:
            return None
        ref = self.reference
        return inlier_landmarks(
            ref.features, self.features, self.matches, self.motion.ref_to_query, ref.c2w, threshold_px
        )

    def against(self, reference: FeatureReference, settings: FeatureSettings) -> FeatureView:
        """This frame's features matched and solved against another ``reference`` (a keyframe)."""
        matches = match_features(reference.features, self.features, MAX_DISTANCE)
        return FeatureView(
            self.features, reference, matches, solve_motion(reference.features, self.features, matches, settings)
        )


class FeatureOdometry:
    """The last accepted frame's features, and the pose of each new frame against them."""

    def __init__(self, settings: FeatureSettings) -> None:
        self.settings = settings
        self._reference: FeatureReference | None = None

    def view(self, frame: Frame) -> FeatureView:
        """``frame``'s features and, with a reference, the pose they give it."""
        s = self.settings
        with stage("features"):
            features = extract_features(frame.rgb, frame.depth, frame.intrinsics, s)
            ref = self._reference
            if ref is None or ref.features.intrinsics != frame.intrinsics:
                return FeatureView(features)
            return FeatureView(features).against(ref, s)

    def accept(self, view: FeatureView, c2w: np.ndarray) -> None:
        """``view``'s frame was accepted at ``c2w`` [4, 4]: it is the next frames' reference."""
        self._reference = FeatureReference(view.features, np.asarray(c2w, dtype=np.float64).copy())
