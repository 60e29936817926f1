"""Frames of the synthetic room at 160x120, rendered on demand (the feature and relocalization tests' input)."""

from __future__ import annotations

from functools import cache

import numpy as np

from sgs_slam_core.frame import Frame
from sgs_slam_core.synthetic.generate import SynthConfig
from sgs_slam_core.synthetic.raycast import raycast
from sgs_slam_core.synthetic.room import build_room
from sgs_slam_core.synthetic.trajectory import make_trajectory

CONFIG = SynthConfig(width=160, height=120, frames=60)
FRAME_NS = 33_333_333


@cache
def poses() -> tuple[np.ndarray, ...]:
    """The orbit's camera-to-world poses, 1.5 degrees apart."""
    scene = build_room(CONFIG.seed)
    return tuple(make_trajectory("orbit", CONFIG.frames, scene.center, CONFIG.step_deg))


@cache
def room_frame(i: int) -> Frame:
    """Frame ``i`` of the orbit (colour, exact depth, labels, ground truth), stamped 30 Hz."""
    c2w = poses()[i]
    rgb, depth, labels = raycast(build_room(CONFIG.seed), CONFIG.intrinsics, c2w, supersample=1)
    return Frame(rgb, depth, CONFIG.intrinsics, labels, i * FRAME_NS, c2w, i)


def relative(i: int, j: int) -> np.ndarray:  # [4, 4]
    """The true motion from frame ``i``'s camera frame to frame ``j``'s."""
    return np.linalg.inv(poses()[j]) @ poses()[i]
