"""When the heap memory the allocator holds free goes back to the operating system (glibc only).

Two rules: the SLAM hands free memory back at keyframes (:func:`release_free_heap`), and not at
every ``free`` in between (:func:`keep_freed_heap`).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import os
from collections.abc import Callable

__all__ = ["HEAP_KEPT_BYTES", "HEAP_PAD_BYTES", "keep_freed_heap", "release_free_heap"]

HEAP_KEPT_BYTES = 256 * 2**20  # free memory at a heap's top kept for reuse instead of returned at a free
HEAP_PAD_BYTES = 64 * 2**20  # extra a heap grows by when it must grow
_M_TRIM_THRESHOLD, _M_TOP_PAD = -1, -2  # glibc's mallopt parameters (malloc.h)
_ENV = ("MALLOC_TRIM_THRESHOLD_", "MALLOC_TOP_PAD_")  # the same settings by environment, which take precedence


def _libc_function(name: str) -> Callable[..., int] | None:
    """The C library's function ``name`` (glibc), or None where it has none (macOS, musl)."""
    try:
        return getattr(ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6"), name)
    except (OSError, AttributeError):
        return None


_TRIM = _libc_function("malloc_trim")
_MALLOPT = _libc_function("mallopt")


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


@functools.cache  # process-wide: set once
def keep_freed_heap() -> bool:
    """Keep up to :data:`HEAP_KEPT_BYTES` of freed memory in the heap for reuse (once per process).

    Every frame allocates and frees buffers of a few MB (images, renderings, gradients, incoming
    messages). By default glibc returns a heap's free top to the OS as soon as it exceeds twice the
    mmap threshold, so the next frame's buffers fault their pages in again: several hundred
    thousand page faults in a 200-frame live run. The keyframes' :func:`release_free_heap` still
    bounds the resident size. False where there is no glibc, or the environment sets these already.
    """
    if _MALLOPT is None or any(name in os.environ for name in _ENV):
        return False
    return bool(_MALLOPT(_M_TRIM_THRESHOLD, HEAP_KEPT_BYTES)) and bool(_MALLOPT(_M_TOP_PAD, HEAP_PAD_BYTES))
