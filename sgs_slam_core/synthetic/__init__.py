"""Synthetic indoor scenes with exact ground truth, by analytic ray casting (independent of the renderer)."""

from sgs_slam_core.synthetic.generate import SYNTH_PRESETS, SynthConfig, generate, preset_config
from sgs_slam_core.synthetic.raycast import raycast
from sgs_slam_core.synthetic.room import Scene, build_room
from sgs_slam_core.synthetic.trajectory import look_at, make_trajectory

__all__ = [
    "SYNTH_PRESETS",
    "Scene",
    "SynthConfig",
    "build_room",
    "generate",
    "look_at",
    "make_trajectory",
    "preset_config",
    "raycast",
]
