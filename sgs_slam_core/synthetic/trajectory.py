"""Smooth camera paths inside the room (camera-to-world, optical frame: x right, y down, z forward)."""

from __future__ import annotations

from typing import Literal

import numpy as np

from sgs_slam_core.geometry.views import look_at

__all__ = ["TrajectoryKind", "look_at", "make_trajectory"]

TrajectoryKind = Literal["orbit", "walk", "look"]


def make_trajectory(kind: TrajectoryKind, frames: int, center: np.ndarray, step_deg: float = 1.5) -> list[np.ndarray]:
    """``frames`` poses; consecutive cameras differ by about ``step_deg`` of rotation."""
    i = np.arange(frames, dtype=np.float64)
    step = np.deg2rad(step_deg)
    poses = []
    if kind == "orbit":
        # On a circle of 1.1 m around the room centre, looking across it at a point 1.5 m beyond the centre.
        for a, h in zip(i * step + 0.3, 1.45 + 0.12 * np.sin(i * step * 1.7), strict=True):
            eye = center + np.array([1.1 * np.cos(a), 1.1 * np.sin(a), h - center[2]])
            target = center + np.array([-1.5 * np.cos(a), -1.5 * np.sin(a), 1.0 - center[2]])
            poses.append(look_at(eye, target))
    elif kind == "walk":
        # Walking an ellipse with a slight bob, looking ahead but turned 35 degrees towards the centre.
        for s in i * step * 0.6:
            eye = center + np.array([1.5 * np.cos(s), 0.8 * np.sin(s), 1.5 + 0.03 * np.sin(6 * s) - center[2]])
            tangent = np.array([-1.5 * np.sin(s), 0.8 * np.cos(s), 0.0])
            tangent /= np.linalg.norm(tangent)
            inward = np.array([-tangent[1], tangent[0], 0.0])  # left of the walking direction
            heading = np.cos(np.radians(35)) * tangent + np.sin(np.radians(35)) * inward
            poses.append(look_at(eye, eye + heading + np.array([0.0, 0.0, -0.2])))
    elif kind == "look":
        # Standing in the middle, turning the head left and right and nodding a little.
        eye = center + np.array([0.0, 0.0, 1.55 - center[2]])
        for t in i * step:
            yaw = 1.1 * np.sin(t * 0.9)
            pitch = -0.25 + 0.15 * np.sin(t * 1.3)
            d = np.array([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)])
            poses.append(look_at(eye, eye + d))
    else:
        raise ValueError(f"unknown trajectory {kind!r}")
    return poses
