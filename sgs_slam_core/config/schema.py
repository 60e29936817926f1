"""The SLAM configuration schema: one typed section per subsystem."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from sgs_slam_core.errors import ConfigError
from sgs_slam_core.render.settings import RenderSettings
from sgs_slam_core.semantics import SemanticSettings
from sgs_slam_core.slam.settings import (
    DensifySettings,
    GuardSettings,
    KeyframeSettings,
    LiveSettings,
    MappingSettings,
    TrackingSettings,
)

__all__ = ["DeviceName", "SlamConfig"]

DeviceName = Literal["auto", "cpu", "cuda"]


@dataclass(frozen=True)
class SlamConfig:
    """Everything a run needs; presets and YAML files are deltas over these defaults.

    Attributes:
        device: ``auto`` uses CUDA when available.
        seed: seeds the run's random choices (keyframe sampling, capped densification).
        eval_every: offline evaluation renders frame 0 and every frame with (t + 1) % eval_every == 0.
    """

    tracking: TrackingSettings = field(default_factory=TrackingSettings)
    mapping: MappingSettings = field(default_factory=MappingSettings)
    densify: DensifySettings = field(default_factory=DensifySettings)
    keyframes: KeyframeSettings = field(default_factory=KeyframeSettings)
    guard: GuardSettings = field(default_factory=GuardSettings)
    render: RenderSettings = field(default_factory=RenderSettings)
    semantic: SemanticSettings = field(default_factory=SemanticSettings)
    live: LiveSettings = field(default_factory=LiveSettings)
    device: DeviceName = "auto"
    seed: int = 0
    eval_every: int = 5

    def __post_init__(self) -> None:
        if self.seed < 0:
            raise ConfigError(f"seed must be >= 0, got {self.seed}")
        if self.eval_every < 1:
            raise ConfigError(f"eval_every must be >= 1, got {self.eval_every}")
