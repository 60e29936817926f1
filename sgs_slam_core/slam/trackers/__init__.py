"""Trackers behind one interface, chosen by ``tracking.method``."""

from __future__ import annotations

from sgs_slam_core.config.sections import TrackingSettings
from sgs_slam_core.render.settings import RenderSettings
from sgs_slam_core.slam.trackers.adam import AdamTracker
from sgs_slam_core.slam.trackers.base import Tracker
from sgs_slam_core.slam.trackers.gauss_newton import GaussNewtonTracker

__all__ = ["AdamTracker", "GaussNewtonTracker", "Tracker", "build_tracker"]


def build_tracker(settings: TrackingSettings, render_settings: RenderSettings) -> Tracker:
    """The tracker ``settings.method`` names."""
    if settings.method == "gauss_newton":
        return GaussNewtonTracker(settings, render_settings)
    return AdamTracker(settings, render_settings)
