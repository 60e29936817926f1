"""``run.yaml``: where a run's frames came from (input, format, options, topics) and how it ended.

Written at the start of a run (``status: running``) and rewritten at its end with ``status``
``complete``, ``interrupted`` (Ctrl-C; the folder holds the frames processed before it),
``evaluation_failed`` (trajectory and map written, metrics not) or ``failed`` (an output could not
be written), plus a one-line ``note``. :func:`read_run_info` validates it for ``sgs-slam eval``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from sgs_slam_core.datasets.base import DatasetOptions
from sgs_slam_core.errors import DatasetError
from sgs_slam_core.fileio import read_yaml, write_text
from sgs_slam_core.validate import as_float, as_int

__all__ = ["RUN_STATUSES", "RunInfo", "read_run_info", "write_run_info"]

RUN_STATUSES = ("running", "complete", "interrupted", "evaluation_failed", "failed")
_OPTION_KEYS = ("start", "stride", "max_frames", "downscale")


@dataclass(frozen=True)
class RunInfo:
    """The validated contents of a ``run.yaml``."""

    input: Path | None
    format: str = "auto"
    options: DatasetOptions = field(default_factory=DatasetOptions)
    topics: dict[str, str] = field(default_factory=dict)
    status: str | None = None  # None: written before statuses existed
    note: str = ""


def write_run_info(path: Path, provenance: dict[str, Any], status: str, note: str = "", **details: Any) -> None:
    """Write ``provenance`` plus ``status``, ``note`` and ``details`` (e.g. frames_processed), atomically."""
    if status not in RUN_STATUSES:
        raise ValueError(f"unknown run status {status!r}")
    data = {**provenance, "status": status, **({"note": note} if note else {}), **details}
    write_text(path, yaml.safe_dump(data, sort_keys=False, allow_unicode=True))


def _options(value: object, where: str) -> DatasetOptions:
    if value is None:
        return DatasetOptions()
    if not isinstance(value, dict):
        raise DatasetError(f"{where}: expected a mapping of {', '.join(_OPTION_KEYS)}")
    unknown = sorted(str(k) for k in value if k not in _OPTION_KEYS)
    if unknown:
        raise DatasetError(f"{where}: unknown keys {unknown} (known: {', '.join(_OPTION_KEYS)})")
    max_frames = value.get("max_frames")
    return DatasetOptions(
        start=as_int(value.get("start", 0), f"{where}.start", DatasetError, 0),
        stride=as_int(value.get("stride", 1), f"{where}.stride", DatasetError, 1),
        max_frames=None if max_frames is None else as_int(max_frames, f"{where}.max_frames", DatasetError, 1),
        downscale=as_float(value.get("downscale", 1.0), f"{where}.downscale", DatasetError, 1.0),
    )


def _text(value: object, where: str) -> str:
    if not isinstance(value, str):
        raise DatasetError(f"{where}: expected text, got {value!r}")
    return value


def read_run_info(run_dir: Path) -> RunInfo:
    """The validated ``run.yaml`` of a run folder; anything missing or malformed raises :class:`DatasetError`."""
    path = run_dir / "run.yaml"
    if not path.is_file():
        raise DatasetError(f"{run_dir} is not a run folder (no run.yaml)")
    data = read_yaml(path, "run file")
    if not isinstance(data, dict):
        raise DatasetError(f"{path}: expected a mapping (input, format, options, ...), got {type(data).__name__}")
    source = data.get("input")
    topics = data.get("topics") or {}
    if not isinstance(topics, dict):
        raise DatasetError(f"{path}: topics: expected a mapping of stream to topic")
    status = data.get("status")
    if status is not None and status not in RUN_STATUSES:
        raise DatasetError(f"{path}: status: {status!r} is not one of {', '.join(RUN_STATUSES)}")
    return RunInfo(
        input=None if source in (None, "") else Path(_text(source, f"{path}: input")),
        format=_text(data.get("format", "auto"), f"{path}: format"),
        options=_options(data.get("options"), f"{path}: options"),
        topics={_text(k, f"{path}: topics"): _text(v, f"{path}: topics.{k}") for k, v in topics.items()},
        status=status,
        note=str(data.get("note", "")),
    )
