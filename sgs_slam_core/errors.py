"""Typed errors of the ROS-free core.

Every error the core raises on bad input derives from :class:`SgsSlamError`, so the CLI can
print one line and exit 1, and a ROS node can log, count and keep running.
"""

from __future__ import annotations

__all__ = [
    "BackendUnavailableError",
    "ConfigError",
    "DatasetError",
    "EditError",
    "EvaluationError",
    "FrameError",
    "MapFileError",
    "OutputError",
    "SgsSlamError",
    "ShapeError",
]


class SgsSlamError(Exception):
    """Base class of every error raised by ``sgs_slam_core``."""


class ConfigError(SgsSlamError):
    """A configuration file, preset or override is invalid (unknown key, wrong type, bad range)."""


class ShapeError(SgsSlamError, ValueError):
    """A tensor or array has the wrong shape, dtype or device."""


class FrameError(SgsSlamError, ValueError):
    """An RGB-D frame is unusable (missing or invalid depth, mismatched sizes, bad dtype)."""


class DatasetError(SgsSlamError):
    """A dataset folder or file is missing or corrupt; the message names the file."""


class EditError(SgsSlamError, ValueError):
    """A map edit cannot be applied (unknown class, empty selection, bad parameters, nothing to undo)."""


class MapFileError(SgsSlamError):
    """A saved map is unreadable (version, missing fields, shape mismatch, truncated file)."""


class BackendUnavailableError(SgsSlamError):
    """A requested renderer backend cannot run here (e.g. gsplat without CUDA)."""


class OutputError(SgsSlamError):
    """A file or folder cannot be written (read-only, disk full, a file where a folder belongs); names it.

    What was written before stays complete, and the file that failed is left absent (writes are atomic).
    """


class EvaluationError(SgsSlamError):
    """Evaluating a finished run failed; the run's trajectory and map were written before it."""
