"""Profiler labels that cost nothing while no profiler runs."""

from __future__ import annotations

from contextlib import AbstractContextManager, nullcontext

import torch
from torch.profiler import record_function

__all__ = ["stage"]


def stage(label: str) -> AbstractContextManager[object]:
    """``torch.profiler.record_function(label)`` while a profiler runs, else a no-op.

    record_function costs microseconds even with no profiler, and the SLAM's loops enter hundreds of
    labels a frame.
    """
    return record_function(label) if torch._C._autograd._profiler_enabled() else nullcontext()
