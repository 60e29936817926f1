"""Tracking-failure guard: judges each tracked pose and knows when the camera is lost.

A pose fails when its depth residual or loss jumps away from the recent accepted frames, or when
the frame's own features contradict it (evidence that does not move with the map: a map dragged
along with a wrong pose still renders consistently with it). Failed frames are not mapped;
``lost_after`` failures in a row mean the camera is lost, and it stays lost until a relocalized
pose passes the same tests. A failed frame may still be placed by its features alone, against the
last accepted frame; ``max_feature_frames`` such frames in a row (the map disagreeing with each)
mean the features' chain has drifted from the map, and the failures count again.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Literal

import numpy as np

from sgs_slam_core.config.sections import GuardSettings

__all__ = ["FeatureEvidence", "GuardCounts", "TrackingGuard", "TrackingState"]

TrackingState = Literal["ok", "lost", "relocalized"]  # relocalized: the frame that found the camera again
HISTORY = 20  # past accepted frames whose median residual and loss are the reference
MIN_VALID_FRACTION = 0.05  # flag when fewer pixels than this are both measured and well mapped
MIN_RESIDUAL_M = 0.02  # depth residuals below this never flag: the depth camera's noise floor
# A pose that explains at least this share of a feature pose's inliers, with at least
# ``guard.relocalize_min_inliers`` of them, is confirmed by the frames themselves: a jump in its
# depth residual or loss then says the map is wrong there (new ground, a bad patch), not the pose,
# and refusing to map the frame would keep the map wrong for every frame after it.
CONFIRMED_AGREEMENT = 0.9
# Turned further than this from a feature pose with ``guard.relocalize_min_inliers`` inliers, a
# pose fails however many matches it explains: a turn traded for a slide reprojects a desk at one
# depth almost alike. The feature pose's own error stays under 1.8 deg on TUM fr1/desk and under
# 2 deg in the synthetic room; the traded turns seen on fr1/desk were 7-9 deg. Translation is not
# compared: the features fix it only as well as the scene's depth allows.
MAX_FEATURE_TURN_DEG = 5.0


@dataclass(frozen=True)
class FeatureEvidence:
    """What a frame's own feature matches say of a tracked pose (``FeatureView``, against its reference)."""

    agreement: float  # share of the feature pose's inlier matches the pose explains, in [0, 1]
    inliers: int  # the feature pose's inlier matches
    turn_deg: float  # rotation between the pose and the feature pose (deg)


@dataclass(frozen=True)
class GuardCounts:
    """How often tracking was lost and found again over a run."""

    lost_events: int  # times the camera became lost
    relocalizations: int  # times a lost camera was found again
    frames_while_lost: int  # frames whose state was lost (the one that found it again excluded)


class TrackingGuard:
    """Compares each frame's depth residual, per-pixel loss and mapped fraction with the recent median."""

    def __init__(self, settings: GuardSettings) -> None:
        self.s = settings
        self._residuals: deque[float] = deque(maxlen=HISTORY)
        self._losses: deque[float] = deque(maxlen=HISTORY)
        self.seen = 0
        self.state: TrackingState = "ok"
        self._failures_in_row = 0
        self._lost_events = 0
        self._relocalizations = 0
        self._frames_while_lost = 0
        self._feature_streak = 0  # frames in a row placed by their features alone, the map disagreeing

    @property
    def lost(self) -> bool:
        """True while the camera is lost (frames are then relocalized, not tracked)."""
        return self.state == "lost"

    def counts(self) -> GuardCounts:
        """Lost events, relocalizations and frames lost so far."""
        return GuardCounts(self._lost_events, self._relocalizations, self._frames_while_lost)

    def check(
        self,
        residual_m: float,
        loss_per_pixel: float,
        valid_fraction: float,
        features: FeatureEvidence | None = None,
    ) -> str | None:
        """The reason the frame failed, or None. Accepted frames join the history."""
        self.seen += 1
        reason = self.judge(residual_m, loss_per_pixel, valid_fraction, features)
        if reason is None:
            self.accept(residual_m, loss_per_pixel)
        return reason

    def accept(self, residual_m: float, loss_per_pixel: float) -> None:
        """Add an accepted frame's residual and loss to the history."""
        self._residuals.append(residual_m)
        self._losses.append(loss_per_pixel)

    def judge(
        self,
        residual_m: float,
        loss_per_pixel: float,
        valid_fraction: float,
        features: FeatureEvidence | None = None,
    ) -> str | None:
        """The reason a tracking result would fail, or None; the history is left as it is.

        ``features``: what the frame's feature pose says of the pose (None: no feature pose to
        check against). A pose the features confirm (:data:`CONFIRMED_AGREEMENT`) is not judged by
        the jumps.
        """
        if not self.s.enabled:
            return None
        unexplained = self._unexplained(residual_m, valid_fraction) or self._contradicted(features)
        if unexplained is not None or self._confirmed(features):
            return unexplained
        return self._jump(residual_m, loss_per_pixel)

    def _strong(self, features: FeatureEvidence | None) -> bool:
        """Whether the feature pose has enough inliers to overrule the dense terms."""
        return features is not None and features.inliers >= self.s.relocalize_min_inliers

    def _confirmed(self, features: FeatureEvidence | None) -> bool:
        """Whether the frame's own feature matches vouch for the pose."""
        return self._strong(features) and features.agreement >= CONFIRMED_AGREEMENT  # type: ignore[union-attr]

    def _contradicted(self, features: FeatureEvidence | None) -> str | None:
        """Why the frame's own feature matches contradict the pose, or None."""
        if features is None:
            return None
        if features.agreement < self.s.min_feature_agreement:
            return f"the pose explains {features.agreement:.0%} of the matches the features' own pose explains"
        if self._strong(features) and features.turn_deg > MAX_FEATURE_TURN_DEG:
            turn, inliers = features.turn_deg, features.inliers
            return f"the pose is turned {turn:.1f} deg from the features' own pose ({inliers} matches)"
        return None

    def _unexplained(self, residual_m: float, valid_fraction: float) -> str | None:
        """Why the pose fails whatever the history: too little mapped to judge it."""
        if valid_fraction < MIN_VALID_FRACTION:
            return f"only {valid_fraction:.1%} of pixels are measured and mapped"
        if not np.isfinite(residual_m):
            return "no pixel to track against"
        return None

    def _jump(self, residual_m: float, loss_per_pixel: float) -> str | None:
        """Why the pose fails against the recent accepted frames' residuals and losses."""
        if self.seen <= self.s.warmup_frames or len(self._residuals) < 2:
            return None
        med_res = float(np.median(self._residuals))
        med_loss = float(np.median(self._losses))
        if residual_m > max(self.s.residual_jump * med_res, MIN_RESIDUAL_M):
            return f"depth residual {residual_m * 100:.1f} cm vs recent {med_res * 100:.1f} cm"
        if med_loss > 0 and loss_per_pixel > self.s.loss_jump * med_loss and residual_m > MIN_RESIDUAL_M:
            return f"tracking loss {loss_per_pixel:.3g}/px vs recent {med_loss:.3g}/px"
        return None

    @property
    def trusts_features(self) -> bool:
        """Whether a frame tracking failed may still be placed by its features alone.

        Each feature pose chains on the last accepted frame, so after ``max_feature_frames`` such
        frames in a row, the tracker disagreeing with every one, the chain is no longer evidence
        (on TUM fr1/desk a drifting chain ran for 200 frames, 28 cm off, while the guard said ok).
        """
        return not self.s.max_feature_frames or self._feature_streak < self.s.max_feature_frames

    def settle(self, failed: bool, located: bool = False, on_features: bool = False) -> TrackingState:
        """The tracking state after a frame tracked (not relocalized) with this outcome.

        ``located``: the frame failed, but its features still place it against the last accepted
        frame, so the camera is not lost (its failures in a row are neither reset nor added to).
        ``on_features``: the frame passed only with its features' pose (the tracker's failed).
        """
        if self.state == "lost":
            self._frames_while_lost += 1
            return self.state
        if not failed:  # a streak grows with each feature pose and ends at the tracker's own
            self._failures_in_row = 0
            self._feature_streak = self._feature_streak + 1 if on_features else 0
        elif not located:
            self._failures_in_row += 1
        if failed and self.s.lost_after and self._failures_in_row >= self.s.lost_after:
            self.state = "lost"
            self._lost_events += 1
            self._frames_while_lost += 1
        else:
            self.state = "ok"
        return self.state

    def start_lost(self) -> None:
        """The camera's place is unknown (a map loaded to resume in): relocalize before tracking."""
        self.state = "lost"

    def relocalized(self) -> TrackingState:
        """A lost camera was found again by this frame: tracking goes on from it."""
        self.state = "relocalized"
        self._relocalizations += 1
        self._failures_in_row = 0
        self._feature_streak = 0
        return self.state
