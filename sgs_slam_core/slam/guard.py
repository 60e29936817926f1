"""Tracking-failure guard: flags frames whose tracking result jumps away from recent history."""

from __future__ import annotations

from collections import deque

import numpy as np

from sgs_slam_core.config.sections import GuardSettings

__all__ = ["TrackingGuard"]


class TrackingGuard:
    """Compares each frame's depth residual, per-pixel loss and mapped fraction with the recent median."""

    def __init__(self, settings: GuardSettings) -> None:
        self.s = settings
        self._residuals: deque[float] = deque(maxlen=settings.history)
        self._losses: deque[float] = deque(maxlen=settings.history)
        self.seen = 0

    def check(self, residual_m: float, loss_per_pixel: float, valid_fraction: float) -> str | None:
        """The reason the frame failed, or None. Accepted frames join the history."""
        self.seen += 1
        if not self.s.enabled:
            return None
        reason = None
        if valid_fraction < self.s.min_valid_fraction:
            reason = f"only {valid_fraction:.1%} of pixels are measured and mapped"
        elif not np.isfinite(residual_m):
            reason = "no pixel to track against"
        elif self.seen > self.s.warmup_frames and len(self._residuals) >= 2:
            med_res = float(np.median(self._residuals))
            med_loss = float(np.median(self._losses))
            if residual_m > max(self.s.residual_jump * med_res, self.s.min_residual_m):
                reason = f"depth residual {residual_m * 100:.1f} cm vs recent {med_res * 100:.1f} cm"
            elif med_loss > 0 and loss_per_pixel > self.s.loss_jump * med_loss and residual_m > self.s.min_residual_m:
                reason = f"tracking loss {loss_per_pixel:.3g}/px vs recent {med_loss:.3g}/px"
        if reason is None:
            self._residuals.append(residual_m)
            self._losses.append(loss_per_pixel)
        return reason
