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
        reason = self.judge(residual_m, loss_per_pixel, valid_fraction)
        if reason is None:
            self.accept(residual_m, loss_per_pixel)
        return reason

    def accept(self, residual_m: float, loss_per_pixel: float) -> None:
        """Add an accepted frame's residual and loss to the history."""
        self._residuals.append(residual_m)
        self._losses.append(loss_per_pixel)

    def judge(self, residual_m: float, loss_per_pixel: float, valid_fraction: float) -> str | None:
        """The reason a tracking result would fail, or None; the history is left as it is."""
        if not self.s.enabled:
            return None
        if valid_fraction < self.s.min_valid_fraction:
            return f"only {valid_fraction:.1%} of pixels are measured and mapped"
        if not np.isfinite(residual_m):
            return "no pixel to track against"
        if self.seen > self.s.warmup_frames and len(self._residuals) >= 2:
            med_res = float(np.median(self._residuals))
            med_loss = float(np.median(self._losses))
            if residual_m > max(self.s.residual_jump * med_res, self.s.min_residual_m):
                return f"depth residual {residual_m * 100:.1f} cm vs recent {med_res * 100:.1f} cm"
            if med_loss > 0 and loss_per_pixel > self.s.loss_jump * med_loss and residual_m > self.s.min_residual_m:
                return f"tracking loss {loss_per_pixel:.3g}/px vs recent {med_loss:.3g}/px"
        return None
