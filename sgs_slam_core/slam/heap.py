"""Handing the heap memory the allocator holds free back to the operating system (glibc only)."""

from __future__ import annotations

import ctypes
import ctypes.util
from collections.abc import Callable

__all__ = ["release_free_heap"]


def _malloc_trim() -> Callable[[int], int] | None:
    """The C library's ``malloc_trim`` (glibc), or None where it has none (macOS, musl)."""
    try:
        return ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").malloc_trim
    except (OSError, AttributeError):
        return None


_TRIM = _malloc_trim()


def release_free_heap() -> bool:
    """Return the free pages inside the heap to the OS; False where that is not possible.

    CPU tensors of a few MB whose sizes change every frame (the map's) come from the heap once
    glibc has raised its mmap threshold, and freed they stay in the process: the resident size then
    climbs for hours while the live data stays flat. Takes tens of ms on a heap of a few GB.
    """
    if _TRIM is None:
        return False
    _TRIM(0)
    return True
