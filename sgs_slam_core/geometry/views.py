"""Camera placement: look-at poses, orbits, and which views lie near a pose.

Poses are camera-to-world, optical frame x right, y down, z forward.
"""

from __future__ import annotations

import numpy as np

from sgs_slam_core.errors import ShapeError

__all__ = ["WORLD_UP", "look_at", "orbit_poses", "views_near"]

WORLD_UP = np.array([0.0, 0.0, 1.0])
WORLD_UP.flags.writeable = False


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = WORLD_UP) -> np.ndarray:  # [4, 4]
    """c2w of a camera at ``eye`` (m) looking at ``target`` (m), image top towards ``up``."""
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    forward = target - eye
    if np.linalg.norm(forward) == 0:
        raise ShapeError("look_at needs eye and target apart")
    forward = forward / np.linalg.norm(forward)
    right = np.cross(forward, up)
    if np.linalg.norm(right) < 1e-9:
        raise ShapeError("look_at: the viewing direction is parallel to up")
    right = right / np.linalg.norm(right)
    down = np.cross(forward, right)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([right, down, forward], axis=1)
    pose[:3, 3] = eye
    return pose


def orbit_poses(
    center: np.ndarray,  # [3] m
    radius: float,  # m, horizontal distance from the centre
    elevation_deg: float,  # camera height above the centre, as an angle
    count: int,
    up: np.ndarray = WORLD_UP,  # [3] world up
) -> list[np.ndarray]:
    """``count`` cameras evenly spaced on a circle around ``center``, all looking at it."""
    if count < 1 or not radius > 0:
        raise ShapeError(f"an orbit needs count >= 1 and radius > 0, got {count}, {radius}")
    up = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    a = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(up, a)
    height = radius * np.tan(np.radians(elevation_deg))
    poses = []
    for angle in np.linspace(0.0, 2 * np.pi, count, endpoint=False):
        eye = center + radius * (np.cos(angle) * a + np.sin(angle) * b) + height * up
        poses.append(look_at(eye, center, up))
    return poses


def views_near(
    centres: np.ndarray,  # [K, 3] m, camera centres in the world
    axes: np.ndarray,  # [K, 3] unit optical axes in the world
    c2w: np.ndarray,  # [4, 4]
    radius_m: float,
    angle_deg: float,
) -> np.ndarray:  # [K] bool
    """Which views lie within ``radius_m`` (m) of ``c2w``'s centre and ``angle_deg`` (degrees) of its axis."""
    close = np.linalg.norm(centres - c2w[:3, 3], axis=1) <= radius_m
    aligned = axes @ c2w[:3, 2] >= np.cos(np.radians(angle_deg))
    return close & aligned
