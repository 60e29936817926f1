"""Relocalization: candidate poses for a lost frame from the keyframes' features.

Each held keyframe's ORB features are computed once from its stored images (so a loaded map's
keyframes serve too). A lost frame's descriptors vote for the keyframe holding their nearest
neighbour; the best-voted keyframes are matched properly and solved by RANSAC PnP on their depth,
giving poses in the map frame that the tracker then refines and the guard judges.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from sgs_slam_core.config.sections import FeatureSettings
from sgs_slam_core.frame import CompactFrame
from sgs_slam_core.profiling import stage
from sgs_slam_core.slam.feature_odometry import FeatureReference, FeatureView
from sgs_slam_core.slam.features import MAX_DISTANCE, extract_features

__all__ = ["Relocalizer"]


class Relocalizer:
    """The keyframes' features, kept in step with the keyframe store, and the poses they give."""

    def __init__(self, settings: FeatureSettings, candidates: int, min_inliers: int) -> None:
        """``candidates``: keyframes solved per lost frame; ``min_inliers``: matches a pose needs."""
        self.settings, self.count, self.min_inliers = settings, candidates, min_inliers
        self._keyframes: dict[int, FeatureReference] = {}

    @property
    def held(self) -> list[int]:
        """Frame indices of the keyframes whose features are held, ascending."""
        return sorted(self._keyframes)

    def candidates(self, keyframes: Sequence[CompactFrame], query: FeatureView) -> list[FeatureView]:
        """``query`` solved against the keyframes it matches best: those with a pose, most inliers first."""
        with stage("relocalize"):
            held = self._sync(keyframes)
            found = []
            for kf in self._ranked(held, query)[: self.count]:
                view = query.against(kf, self.settings)
                if view.inliers >= self.min_inliers:
                    found.append(view)
            return sorted(found, key=lambda v: -v.inliers)

    def _sync(self, keyframes: Sequence[CompactFrame]) -> list[FeatureReference]:
        """The held keyframes' features: computed for new ones, dropped for those the store let go."""
        held = {}
        for kf in keyframes:
            known = self._keyframes.get(kf.index)
            if known is None:
                features = extract_features(kf.rgb, kf.depth_m, kf.intrinsics, self.settings)
                known = FeatureReference(features, np.linalg.inv(kf.w2c), kf.index)
            held[kf.index] = known
        self._keyframes = held
        return list(held.values())

    def _ranked(self, held: list[FeatureReference], query: FeatureView) -> list[FeatureReference]:
        """Keyframes by the votes of ``query``'s descriptors (each votes for its nearest keyframe descriptor)."""
        features = query.features
        usable = [kf for kf in held if len(kf.features) and kf.features.intrinsics == features.intrinsics]
        if not usable or not len(features):
            return []
        matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
        matcher.add([kf.features.descriptors for kf in usable])
        votes = np.zeros(len(usable), dtype=np.int64)
        for m in matcher.match(features.descriptors):
            if m.distance <= MAX_DISTANCE:
                votes[m.imgIdx] += 1
        order = np.argsort(-votes, kind="stable")
        return [usable[i] for i in order if votes[i] > 0]
