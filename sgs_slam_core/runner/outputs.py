"""The run folder: creating it, writing its files atomically, and removing an aborted run.

Order of a run (``run_offline``): ``config.yaml`` and ``run.yaml`` (status ``running``) first;
after the last frame the results, smallest and most valuable first (``trajectory.txt``,
``frames.csv``, ``map.sgsmap``, ``map.ply``); then the evaluation (``renders/``,
``trajectory.png``, ``metrics.json``); ``run.yaml`` is rewritten last with how the run ended. Every
file is written atomically, so each is complete or absent whatever fails.
"""

from __future__ import annotations

import contextlib
import csv
import io
import shutil
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from sgs_slam_core.errors import DatasetError, OutputError
from sgs_slam_core.fileio import make_dir, write_text

__all__ = ["RESULT_FILES", "RUN_FILES", "check_run_dir", "prepare_run_dir", "remove_run", "write_csv"]

RESULT_FILES = ("trajectory.txt", "frames.csv", "map.sgsmap", "map.ply")
RUN_FILES = ("config.yaml", "run.yaml", *RESULT_FILES, "metrics.json", "trajectory.png", "renders")


def _occupied(out: Path) -> bool:
    try:
        return out.exists() and (not out.is_dir() or any(out.iterdir()))
    except OSError as err:
        raise OutputError(f"cannot look into output folder {out}: {err.strerror or err}") from err


def check_run_dir(out: Path, overwrite: bool) -> None:
    """Raise unless ``out`` is absent, an empty folder, or a folder that may be replaced (call before any work)."""
    if out.exists() and not out.is_dir():
        raise OutputError(f"output folder {out} exists and is a file (give a folder)")
    if _occupied(out) and not overwrite:
        raise DatasetError(f"output folder {out} exists and is not empty (use --overwrite to replace it)")


def prepare_run_dir(out: Path, overwrite: bool) -> bool:
    """Create ``out`` (an existing non-empty folder only with ``overwrite``: then replaced).

    Returns True when the folder did not exist before (an aborted run then removes it).
    """
    check_run_dir(out, overwrite)
    created = not out.exists()
    if _occupied(out):
        try:
            shutil.rmtree(out)
        except OSError as err:
            raise OutputError(f"cannot replace output folder {out}: {err.strerror or err}") from err
        created = True
    make_dir(out)
    return created


def remove_run(out: Path, created: bool) -> None:
    """Remove what a run wrote to ``out`` (and ``out`` itself when the run created it); never raises."""
    try:
        temps = list(out.glob(".*.tmp"))  # a write interrupted between its temporary file and the rename
    except OSError:
        temps = []
    for target in [*(out / name for name in RUN_FILES), *temps]:
        try:
            if target.is_dir():
                shutil.rmtree(target, ignore_errors=True)
            else:
                target.unlink(missing_ok=True)
        except OSError:
            pass
    if created:
        with contextlib.suppress(OSError):  # something else lives there: leave it
            out.rmdir()


def write_csv(path: Path, fields: Sequence[str], rows: Iterable[dict[str, Any]]) -> None:
    """A CSV with a header row, written atomically."""
    buffer = io.StringIO(newline="")
    writer = csv.DictWriter(buffer, fieldnames=list(fields))
    writer.writeheader()
    writer.writerows(rows)
    write_text(path, buffer.getvalue())
