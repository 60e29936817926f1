"""Typed errors of the message adapters."""

from __future__ import annotations

__all__ = ["AdapterError"]


class AdapterError(ValueError):
    """A message cannot be converted; the text names the field and what is wrong with it."""
