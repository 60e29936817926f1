"""Typed fields read from user files: a number that is not one, or out of range, raises the caller's error.

``where`` names the file and the field (``"camera.yaml: fx"``), so every message says what to fix.
Booleans are not numbers here (YAML reads ``yes`` as ``True``, which ``int()`` would take for 1).
"""

from __future__ import annotations

import math
import numbers

from sgs_slam_core.errors import SgsSlamError

__all__ = ["as_float", "as_int"]


def as_float(
    value: object,
    where: str,
    error: type[SgsSlamError],
    lo: float | None = None,
    hi: float | None = None,
    lo_open: bool = False,
) -> float:
    """A finite float in ``[lo, hi]`` (``(lo, hi]`` with ``lo_open``) from a number or a numeric string."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real | str):
        raise error(f"{where}: expected a number, got {value!r}")
    try:
        number = float(value)
    except ValueError:
        raise error(f"{where}: expected a number, got {value!r}") from None
    if not math.isfinite(number):
        raise error(f"{where}: expected a finite number, got {value!r}")
    if lo is not None and (number <= lo if lo_open else number < lo):
        raise error(f"{where}: must be {'>' if lo_open else '>='} {lo:g}, got {number:g}")
    if hi is not None and number > hi:
        raise error(f"{where}: must be <= {hi:g}, got {number:g}")
    return number


def as_int(value: object, where: str, error: type[SgsSlamError], lo: int | None = None, hi: int | None = None) -> int:
    """An integer in ``[lo, hi]`` from an int, an integral float (``640.0``) or a decimal string."""
    if isinstance(value, bool):
        raise error(f"{where}: expected an integer, got {value!r}")
    integral = isinstance(value, numbers.Integral)
    integral |= isinstance(value, numbers.Real) and math.isfinite(value) and float(value).is_integer()
    integral |= isinstance(value, str) and value.strip().lstrip("+-").isdigit()
    if not integral:
        raise error(f"{where}: expected an integer, got {value!r}")
    number = int(value)  # type: ignore[call-overload]
    if (lo is not None and number < lo) or (hi is not None and number > hi):
        bounds = f"{'' if lo is None else lo}..{'' if hi is None else hi}"
        raise error(f"{where}: must be in {bounds}, got {number}")
    return number
