"""The SLAM configuration schema: one typed section per subsystem."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from sgs_slam_core.errors import ConfigError
from sgs_slam_core.render.settings import RenderSettings
from sgs_slam_core.semantics import SemanticSettings

__all__ = ["DeviceName", "SlamConfig"]

DeviceName = Literal["auto", "cpu", "cuda"]


@dataclass(frozen=True)
class SlamConfig:
    """Everything a run needs; presets and YAML files are deltas over these defaults.

    Attributes:
        device: ``auto`` uses CUDA when available.
        seed: seeds torch and numpy for a deterministic run on CPU.
    """

    render: RenderSettings = field(default_factory=RenderSettings)
    semantic: SemanticSettings = field(default_factory=SemanticSettings)
    device: DeviceName = "auto"
    seed: int = 0

    def __post_init__(self) -> None:
        if self.seed < 0:
            raise ConfigError(f"seed must be >= 0, got {self.seed}")
