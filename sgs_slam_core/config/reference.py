"""The configuration reference (``docs/config.md``), generated from the config dataclasses.

Every key of :class:`~sgs_slam_core.config.SlamConfig` with its default and the description its
section's docstring gives under ``Attributes:``, then what each preset changes. Run
``python -m sgs_slam_core.config.reference > docs/config.md`` after changing a section; a test
keeps the file in step.
"""

from __future__ import annotations

import dataclasses
import fnmatch
import inspect
import re
from typing import Any

import yaml

from sgs_slam_core.config.loader import config_fields, list_presets, preset_data
from sgs_slam_core.config.schema import SlamConfig

__all__ = ["attribute_docs", "config_keys", "config_reference"]

_ATTRIBUTE = re.compile(r"^([\w*]+(?:,\s*[\w*]+)*):\s*(.*)$")  # "name: ...", "a, b: ...", "lr_*: ..."


def attribute_docs(cls: type) -> dict[str, str]:
    """``name -> description`` from the ``Attributes:`` section of ``cls``'s docstring (lines joined)."""
    doc = inspect.getdoc(cls) or ""
    lines = doc.split("Attributes:", 1)[1].splitlines() if "Attributes:" in doc else []
    found: dict[str, str] = {}
    name = None
    indent = None
    for line in lines:
        if not line.strip():
            name = None
            continue
        depth = len(line) - len(line.lstrip())
        indent = depth if indent is None else indent
        match = _ATTRIBUTE.match(line.strip())
        if depth == indent and match:
            name = match.group(1)
            found[name] = match.group(2)
        elif name is not None and depth > indent:
            found[name] += " " + line.strip()
    return {field: text for names, text in found.items() for field in _fields_named(cls, names)}


def _fields_named(cls: type, names: str) -> list[str]:
    """The fields an ``Attributes:`` entry names: one, several (``a, b``) or a pattern (``lr_*``)."""
    declared = [f.name for f in dataclasses.fields(cls)] if dataclasses.is_dataclass(cls) else []
    found = []
    for name in (n.strip() for n in names.split(",")):
        found += fnmatch.filter(declared, name) if "*" in name else [name]
    return found


def config_keys(obj: Any = None, prefix: str = "") -> list[tuple[str, Any, str]]:
    """``(dotted key, default, description)`` of every leaf setting, in declaration order."""
    obj = SlamConfig() if obj is None else obj
    docs = attribute_docs(type(obj))
    rows: list[tuple[str, Any, str]] = []
    for f in config_fields(obj):
        value = getattr(obj, f.name)
        key = f"{prefix}{f.name}"
        if dataclasses.is_dataclass(value) and f.name in docs and not _is_section(value):
            rows.append((key, value, docs[f.name]))  # a value type (e.g. the depth-noise model), one key
        elif dataclasses.is_dataclass(value):
            rows += config_keys(value, key + ".")
        else:
            rows.append((key, value, docs.get(f.name, "")))
    return rows


def _is_section(value: Any) -> bool:
    """A settings section (its own keys documented in its own docstring), not a value made of fields."""
    return "Attributes:" in (inspect.getdoc(type(value)) or "") and type(value).__name__.endswith("Settings")


def _text(value: Any) -> str:
    if dataclasses.is_dataclass(value):
        value = dataclasses.asdict(value)
    if isinstance(value, tuple):
        value = list(value)
    return "`" + yaml.safe_dump(value, default_flow_style=True, width=10_000).strip().removesuffix("...").strip() + "`"


def _presets() -> list[tuple[str, dict[str, Any]]]:
    """Each preset's keys (its ``extends:`` chain resolved), flattened to dotted names."""
    return [(name, _flatten(preset_data(name))) for name in list_presets()]


def _flatten(data: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    flat: dict[str, Any] = {}
    for key, value in data.items():
        if isinstance(value, dict) and key != "depth_noise":
            flat.update(_flatten(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def config_reference() -> str:
    """``docs/config.md``: every key, its default and description, then the presets' changes."""
    keys = config_keys()
    out = [
        "# Configuration reference",
        "",
        "Generated from the config dataclasses by `python -m sgs_slam_core.config.reference > docs/config.md`",
        "(a test keeps it in step). A run's settings are these defaults, then a preset, then a YAML file, then",
        "`key=value` overrides (`sgs-slam run --set`, the nodes' `overrides` parameter); live runs then apply",
        f"the `live.*` settings. {len(keys)} keys.",
        "",
        "| key | default | meaning |",
        "|---|---|---|",
    ]
    out += [f"| `{key}` | {_text(default)} | {' '.join(doc.split())} |" for key, default, doc in keys]
    out += ["", "## Presets", "", "What each preset (`config/presets/*.yaml`, `extends:` resolved) sets.", ""]
    for name, values in _presets():
        out += [f"### `{name}`", "", "| key | value |", "|---|---|"]
        out += [f"| `{key}` | {_text(value)} |" for key, value in values.items()]
        out.append("")
    return "\n".join(out).rstrip() + "\n"


if __name__ == "__main__":
    print(config_reference(), end="")
