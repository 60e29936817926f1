"""Typed configuration: dataclass schema, YAML presets, overrides."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from sgs_slam_core.config.loader import build, config_to_dict, dump_yaml, list_presets, load_layers, parse_override
from sgs_slam_core.config.schema import DeviceName, SlamConfig

__all__ = [
    "DeviceName",
    "SlamConfig",
    "build",
    "config_to_dict",
    "dump_yaml",
    "list_presets",
    "load_config",
    "parse_override",
]


def load_config(preset: str | None = None, path: str | Path | None = None, overrides: Iterable[str] = ()) -> SlamConfig:
    """The resolved :class:`SlamConfig`: defaults, preset, YAML file, then ``key=value`` overrides."""
    return load_layers(SlamConfig, preset, path, overrides)
