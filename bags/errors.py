"""Typed errors of the bag tools."""

from __future__ import annotations

from sgs_slam_core.errors import DatasetError

__all__ = ["BagError"]


class BagError(DatasetError):
    """A bag cannot be written or read (exists, corrupt, truncated, missing topics); names the file."""
