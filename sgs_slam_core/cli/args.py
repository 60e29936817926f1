"""Argument types with ranges: a value outside its range is a usage error (exit 2) before any work starts.

Each type renders its range for ``--help`` (:func:`bounds`), so the limits a command enforces are
the limits it documents.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from dataclasses import dataclass

__all__ = [
    "MAX_FRAMES",
    "MAX_IMAGE_SIDE",
    "MAX_SEED",
    "FloatRange",
    "IntRange",
]

MAX_IMAGE_SIDE = 4096  # px: a float32 RGB-D + labels image of 4096x4096 is already ~400 MB per buffer
MAX_FRAMES = 100_000
MAX_SEED = 2**32 - 1  # numpy's seed range


@dataclass(frozen=True)
class IntRange:
    """An integer in ``[lo, hi]`` (``hi`` None: no upper bound)."""

    lo: int
    hi: int | None = None

    def __call__(self, text: str) -> int:
        """Parse ``text``; out of range raises ``ArgumentTypeError`` (argparse: usage, exit 2)."""
        try:
            value = int(text, 10)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < self.lo or (self.hi is not None and value > self.hi):
            raise argparse.ArgumentTypeError(f"{value} is out of range: {self.bounds}")
        return value

    @property
    def bounds(self) -> str:
        """``1..4096`` or ``>= 1``."""
        return f">= {self.lo}" if self.hi is None else f"{self.lo}..{self.hi}"

    def __repr__(self) -> str:  # argparse names the type in "invalid <type> value" messages
        return "integer"


@dataclass(frozen=True)
class FloatRange:
    """A finite float in ``[lo, hi]`` (``lo_open`` / ``hi_open`` exclude the end; None: unbounded)."""

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False

    def __call__(self, text: str) -> float:
        """Parse ``text``; non-finite or out of range raises ``ArgumentTypeError``."""
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        below: Callable[[float, float], bool] = (lambda v, b: v <= b) if self.lo_open else (lambda v, b: v < b)
        above: Callable[[float, float], bool] = (lambda v, b: v >= b) if self.hi_open else (lambda v, b: v > b)
        if (
            not math.isfinite(value)
            or (self.lo is not None and below(value, self.lo))
            or (self.hi is not None and above(value, self.hi))
        ):
            raise argparse.ArgumentTypeError(f"{text} is out of range: {self.bounds}")
        return value

    @property
    def bounds(self) -> str:
        """``[0, 1)``, ``> 0``, ``>= 1`` or ``any finite number``."""
        if self.lo is not None and self.hi is not None:
            return f"{'(' if self.lo_open else '['}{self.lo:g}, {self.hi:g}{')' if self.hi_open else ']'}"
        if self.lo is not None:
            return f"{'>' if self.lo_open else '>='} {self.lo:g}"
        if self.hi is not None:
            return f"{'<' if self.hi_open else '<='} {self.hi:g}"
        return "any finite number"

    def __repr__(self) -> str:
        return "number"
