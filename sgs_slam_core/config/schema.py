"""The SLAM configuration schema: one typed section per subsystem."""

from __future__ import annotations

from dataclasses import dataclass, field, is_dataclass, replace
from typing import Any, Literal

from sgs_slam_core.config.loader import build, config_fields, config_to_dict, merge
from sgs_slam_core.config.sections import (
    DensifySettings,
    FeatureSettings,
    GuardSettings,
    KeyframeSettings,
    LiveSettings,
    MapFrameSettings,
    MappingSettings,
    MotionSettings,
    TrackingSettings,
)
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
        seed: seeds the run's random choices (keyframe sampling, capped densification).
        eval_every: offline evaluation renders frame 0 and every frame with (t + 1) % eval_every == 0.
    """

    map_frame: MapFrameSettings = field(default_factory=MapFrameSettings)
    motion: MotionSettings = field(default_factory=MotionSettings)
    features: FeatureSettings = field(default_factory=FeatureSettings)
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

    def for_live(self) -> SlamConfig:
        """This config as live runs use it: ``live.overlay``'s keys in place of lockstep's.

        Then ``live.geometry_lr_scale`` multiplies the mapping's centre and size learning rates.
        """
        config = replace(self, **self._overlaid_sections()) if self.live.overlay else self
        scale = self.live.geometry_lr_scale
        if scale != 1.0:
            m = config.mapping
            config = replace(config, mapping=replace(m, lr_means=m.lr_means * scale, lr_scales=m.lr_scales * scale))
        return config

    def _overlaid_sections(self) -> dict[str, Any]:
        """Each section ``live.overlay`` names, with its keys in place (validated as the section is)."""
        sections = {f.name: getattr(self, f.name) for f in config_fields(self)}
        out = {}
        for name, values in self.live.overlay.items():
            current = sections.get(name)
            if name == "live" or not is_dataclass(current):
                raise ConfigError(f"live.overlay.{name}: not a config section ({', '.join(sorted(sections))})")
            out[name] = build(type(current), merge(config_to_dict(current), values), f"live.overlay.{name}")
        return out

    def __post_init__(self) -> None:
        if self.seed < 0:
            raise ConfigError(f"seed must be >= 0, got {self.seed}")
        if self.eval_every < 1:
            raise ConfigError(f"eval_every must be >= 1, got {self.eval_every}")
        self._overlaid_sections()  # a bad live overlay fails where the config is made, not when a live run starts
