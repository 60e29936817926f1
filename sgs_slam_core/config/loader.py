"""Build typed (dataclass) configs from plain data, YAML files, presets and ``key=value`` overrides.

Unknown keys, wrong types and out-of-range values raise :class:`ConfigError` naming the dotted key.
A dataclass field with ``metadata={"internal": True}`` is no config key: it keeps its default here.
Layers apply in order: dataclass defaults, preset (which may ``extends:`` another), YAML file,
overrides.
"""

from __future__ import annotations

import dataclasses
import types
from collections.abc import Iterable, Mapping
from importlib import resources
from pathlib import Path
from typing import Any, Literal, TypeVar, Union, get_args, get_origin, get_type_hints

import yaml

from sgs_slam_core.errors import ConfigError
from sgs_slam_core.fileio import read_yaml, write_text

__all__ = [
    "build",
    "config_fields",
    "config_to_dict",
    "dump_yaml",
    "known_keys",
    "list_presets",
    "load_layers",
    "load_yaml",
    "merge",
    "parse_override",
    "preset_data",
]

T = TypeVar("T")
_PRESET_PACKAGE = "sgs_slam_core.config.presets"


def _type_name(tp: Any) -> str:
    return getattr(tp, "__name__", None) or str(tp).replace("typing.", "")


def _coerce(value: Any, tp: Any, where: str) -> Any:  # noqa: PLR0911, PLR0912 - one branch per type kind
    origin = get_origin(tp)
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, Mapping):
            raise ConfigError(f"{where}: expected a mapping, got {type(value).__name__}")
        return build(tp, value, where)  # type: ignore[arg-type]
    if origin is Literal:
        if value not in get_args(tp):
            raise ConfigError(f"{where}: must be one of {list(get_args(tp))}, got {value!r}")
        return value
    if origin in (Union, types.UnionType):
        args = get_args(tp)
        if value is None and type(None) in args:
            return None
        errors = []
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _coerce(value, arg, where)
            except ConfigError as err:
                errors.append(str(err))
        raise ConfigError(errors[0] if len(errors) == 1 else f"{where}: {value!r} matches none of {_type_name(tp)}")
    if origin in (dict, tuple, list):
        return _coerce_container(value, tp, where)
    if tp is Any:
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true/false, got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        return value
    if tp is float:
        if isinstance(value, str):  # YAML 1.1 reads "1e-3" (no dot) as a string
            try:
                return float(value)
            except ValueError:
                pass
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
        return value
    raise ConfigError(f"{where}: unsupported config type {_type_name(tp)}")


def _coerce_container(value: Any, tp: Any, where: str) -> Any:
    """A mapping of names (``dict[str, Any]``), a list or a tuple, items checked against their types."""
    origin = get_origin(tp)
    if origin is dict:
        if not isinstance(value, Mapping) or not all(isinstance(k, str) for k in value):
            raise ConfigError(f"{where}: expected a mapping of names, got {value!r}")
        return {k: dict(v) if isinstance(v, Mapping) else v for k, v in value.items()}
    if not isinstance(value, list | tuple):
        raise ConfigError(f"{where}: expected a list, got {type(value).__name__}")
    args = get_args(tp)
    if origin is tuple and args and args[-1] is not Ellipsis:
        if len(value) != len(args):
            raise ConfigError(f"{where}: expected {len(args)} values, got {len(value)}")
        items = [_coerce(v, a, f"{where}[{i}]") for i, (v, a) in enumerate(zip(value, args, strict=True))]
    else:
        item_tp = args[0] if args else Any
        items = [_coerce(v, item_tp, f"{where}[{i}]") for i, v in enumerate(value)]
    return tuple(items) if origin is tuple else items


def build(cls: type[T], data: Mapping[str, Any], where: str = "") -> T:
    """Instantiate dataclass ``cls`` from a mapping; missing keys keep their defaults."""
    if not dataclasses.is_dataclass(cls):
        raise TypeError(f"{cls} is not a dataclass")
    hints = get_type_hints(cls)
    known = {f.name for f in config_fields(cls)}
    unknown = sorted(set(data) - known)
    if unknown:
        prefix = f"{where}." if where else ""
        raise ConfigError(f"unknown config key {prefix}{unknown[0]} (known at this level: {', '.join(sorted(known))})")
    defaults = {f.name: f for f in config_fields(cls)}
    kwargs = {
        k: _coerce(_over_default(defaults[k], v, hints[k]), hints[k], f"{where}.{k}" if where else k)
        for k, v in data.items()
    }
    try:
        return cls(**kwargs)
    except ConfigError as err:
        raise ConfigError(f"{where}: {err}" if where else str(err)) from err
    except (TypeError, ValueError) as err:
        raise ConfigError(f"{where or cls.__name__}: {err}") from err


def _over_default(f: dataclasses.Field[Any], value: Any, tp: Any) -> Any:
    """A mapping given for a mapping-typed key merges into the key's default, as the layers merge."""
    if get_origin(tp) is not dict or not isinstance(value, Mapping):
        return value
    default = f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default
    return merge(default, value) if isinstance(default, Mapping) else value


def config_fields(cls: Any) -> list[dataclasses.Field[Any]]:
    """The fields of dataclass ``cls`` (or instance) that are config keys: not internal ones."""
    return [f for f in dataclasses.fields(cls) if f.init and not f.metadata.get("internal")]


def known_keys(cls: type, data: Mapping[str, Any]) -> dict[str, Any]:
    """``data`` without what is no config key of dataclass ``cls``, at any level.

    For configs another version wrote (a saved map's): keys that version had and this one retired
    are dropped instead of failing the load. Files a user writes go through :func:`build` alone.
    """
    hints = get_type_hints(cls)
    known = {f.name for f in config_fields(cls)}
    out: dict[str, Any] = {}
    for key, value in data.items():
        if key in known:
            section = dataclasses.is_dataclass(hints[key]) and isinstance(value, Mapping)
            out[key] = known_keys(hints[key], value) if section else value
    return out


def config_to_dict(obj: Any) -> Any:
    """Plain-data form of a (nested) dataclass config, tuples as lists (YAML friendly); config keys only."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: config_to_dict(getattr(obj, f.name)) for f in config_fields(obj)}
    if isinstance(obj, tuple | list):
        return [config_to_dict(v) for v in obj]
    return obj


def merge(base: Mapping[str, Any], delta: Mapping[str, Any]) -> dict[str, Any]:
    """Recursive dict merge: mappings merge, everything else replaces."""
    out = dict(base)
    for key, value in delta.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = merge(out[key], value)
        else:
            out[key] = value
    return out


def parse_override(text: str) -> dict[str, Any]:
    """``"a.b.c=value"`` -> ``{"a": {"b": {"c": value}}}``; the value is parsed as YAML."""
    key, sep, raw = text.partition("=")
    key = key.strip()
    if not sep or not key or any(not part for part in key.split(".")):
        raise ConfigError(f"override must look like section.key=value, got {text!r}")
    try:
        value = yaml.safe_load(raw) if raw.strip() else ""
    except yaml.YAMLError as err:
        raise ConfigError(f"override {text!r}: value is not valid YAML ({err})") from err
    nested: dict[str, Any] = {}
    cursor = nested
    parts = key.split(".")
    for part in parts[:-1]:
        cursor = cursor.setdefault(part, {})
    cursor[parts[-1]] = value
    return nested


def load_yaml(path: str | Path) -> dict[str, Any]:
    """A YAML mapping from a file (an empty file is an empty mapping)."""
    path = Path(path)
    data = read_yaml(path, "config file", ConfigError) or {}
    if not isinstance(data, dict):
        raise ConfigError(f"config file {path} must hold a mapping at the top level")
    return data


def list_presets() -> list[str]:
    """Names of the built-in presets."""
    root = resources.files(_PRESET_PACKAGE)
    return sorted(p.name[: -len(".yaml")] for p in root.iterdir() if p.name.endswith(".yaml"))


def preset_data(name: str, _seen: tuple[str, ...] = ()) -> dict[str, Any]:
    """A preset's mapping with its ``extends:`` chain resolved."""
    if name in _seen:
        raise ConfigError(f"preset inheritance loop: {' -> '.join((*_seen, name))}")
    resource = resources.files(_PRESET_PACKAGE) / f"{name}.yaml"
    if not resource.is_file():
        raise ConfigError(f"unknown preset {name!r}; available: {', '.join(list_presets())}")
    data = yaml.safe_load(resource.read_text()) or {}
    parent = data.pop("extends", None)
    return merge(preset_data(parent, (*_seen, name)), data) if parent else data


def load_layers(
    cls: type[T],
    preset: str | None = None,
    path: str | Path | None = None,
    overrides: Iterable[str] = (),
) -> T:
    """Defaults, then the preset, then a YAML file, then ``key=value`` overrides."""
    data: dict[str, Any] = {}
    if preset:
        data = merge(data, preset_data(preset))
    if path is not None:
        data = merge(data, load_yaml(path))
    for text in overrides:
        data = merge(data, parse_override(text))
    return build(cls, data)


def dump_yaml(obj: Any, path: str | Path) -> None:
    """Write a config (dataclass or mapping) as YAML, atomically."""
    write_text(path, yaml.safe_dump(config_to_dict(obj), sort_keys=False))
