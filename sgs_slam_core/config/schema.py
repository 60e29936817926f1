"""The SLAM configuration schema: one typed section per subsystem."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Literal

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
        """This config as live runs use it: the ``live`` section's replacements applied.

        ``live.tracking_method`` / ``live.mapping_every`` / ``live.refresh_labels_keyframes_only``
        replace ``tracking.method`` / ``mapping.every`` / ``mapping.refresh_labels_keyframes_only``
        and ``live.mapping_weight_color`` / ``live.densify_depth_error_factor`` replace
        ``mapping.weight_color`` / ``densify.depth_error_factor`` (each, when null, leaves its
        setting as it is); ``live.geometry_lr_scale`` multiplies the mapping's centre and size
        learning rates.
        """
        config, live = self, self.live
        if live.tracking_method is not None and live.tracking_method != config.tracking.method:
            config = replace(config, tracking=replace(config.tracking, method=live.tracking_method))
        mapping = config.mapping
        if live.mapping_every is not None:
            mapping = replace(mapping, every=live.mapping_every)
        if live.refresh_labels_keyframes_only is not None:
            mapping = replace(mapping, refresh_labels_keyframes_only=live.refresh_labels_keyframes_only)
        if live.geometry_lr_scale != 1.0:
            scale = live.geometry_lr_scale
            mapping = replace(mapping, lr_means=mapping.lr_means * scale, lr_scales=mapping.lr_scales * scale)
        if live.mapping_weight_color is not None:
            mapping = replace(mapping, weight_color=live.mapping_weight_color)
        if mapping != config.mapping:
            config = replace(config, mapping=mapping)
        if live.densify_depth_error_factor is not None:
            densify = replace(config.densify, depth_error_factor=live.densify_depth_error_factor)
            config = replace(config, densify=densify)
        return config

    def __post_init__(self) -> None:
        if self.seed < 0:
            raise ConfigError(f"seed must be >= 0, got {self.seed}")
        if self.eval_every < 1:
            raise ConfigError(f"eval_every must be >= 1, got {self.eval_every}")
