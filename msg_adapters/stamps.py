"""builtin_interfaces/Time <-> integer nanoseconds."""

from __future__ import annotations

from typing import Any

__all__ = ["ns_to_stamp", "stamp_to_ns"]


def stamp_to_ns(stamp: Any) -> int:
    """Nanoseconds of a ``Time`` (``sec``, ``nanosec``) of any message flavour."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def ns_to_stamp(ns: int) -> tuple[int, int]:
    """``(sec, nanosec)`` of a time in nanoseconds (negative times are not ROS stamps)."""
    if ns < 0:
        raise ValueError(f"ROS time stamps are non-negative, got {ns} ns")
    return int(ns // 1_000_000_000), int(ns % 1_000_000_000)
