"""Frames that never arrived: gaps in a stream's header stamps against the stream's own period.

A camera (or a bag) stamps its frames at a steady period; a frame lost between the driver and the
node (DDS dropped it, the subscription queue overflowed, the driver skipped it) leaves a gap of
several periods between two received stamps. The period is estimated from the received stamps
themselves (a low quantile of recent stamp differences, so that losses and jitter do not inflate
it), or given (``period_ns``). Nothing here knows about ROS: stamps are integers in nanoseconds.
"""

from __future__ import annotations

import bisect
import threading
from collections import deque
from dataclasses import dataclass

__all__ = ["GapReport", "StreamGaps"]

_WINDOW = 64  # stamp differences kept for the period estimate
_MIN_DIFFS = 8  # differences needed before gaps are judged (the first ones are judged then)
_QUANTILE = 0.2  # low quantile of the differences: robust to up to ~80 % loss and to late frames
_GAP = 1.5  # a difference above this many periods holds at least one lost frame


@dataclass(frozen=True)
class GapReport:
    """One gap: ``lost`` frames missing between two received stamps."""

    lost: int
    gap_ns: int
    period_ns: int


class StreamGaps:
    """Counts frames missing from one stream, judged by the gaps between received stamps.

    Thread-safe. A stamp that is not newer than the previous one (a replay restarted, a reset) starts
    a new sequence without counting anything.
    """

    def __init__(self, period_ns: int | None = None) -> None:
        self.fixed_period_ns = period_ns
        self.lost = 0  # frames missing so far
        self.received = 0  # stamps seen
        self._diffs: deque[int] = deque(maxlen=_WINDOW)  # in arrival order
        # the same differences in ascending order, kept sorted per stamp: the estimate runs on every
        # message of every camera topic, on the executor's thread, where np.quantile's call costs more
        self._sorted: list[int] = []
        self._unjudged: list[int] = []  # differences seen before the period was known
        self._last: int | None = None
        self._lock = threading.Lock()

    @property
    def period_ns(self) -> int | None:
        """The stream's period: the given one, else the estimate (None until enough stamps arrived)."""
        if self.fixed_period_ns is not None:
            return self.fixed_period_ns
        if len(self._sorted) < _MIN_DIFFS:
            return None
        return int(_low_quantile(self._sorted, _QUANTILE))

    def add(self, stamp_ns: int) -> GapReport | None:
        """A stamp arrived; returns the gap it closes when frames are missing before it."""
        with self._lock:
            self.received += 1
            last, self._last = self._last, stamp_ns
            if last is None or stamp_ns <= last:
                return None
            diff = stamp_ns - last
            if len(self._diffs) == _WINDOW:  # the oldest difference leaves the window
                del self._sorted[bisect.bisect_left(self._sorted, self._diffs[0])]
            self._diffs.append(diff)
            bisect.insort(self._sorted, diff)
            period = self.period_ns
            if period is None:
                self._unjudged.append(diff)
                return None
            pending, self._unjudged = [*self._unjudged, diff], []
            lost = sum(_missing(d, period) for d in pending)
            self.lost += lost
            return GapReport(lost, max(pending), period) if lost else None

    def reset(self) -> None:
        """Start a new sequence (the counts stay)."""
        with self._lock:
            self._last = None
            self._unjudged.clear()


def _low_quantile(ascending: list[int], q: float) -> float:
    """The ``q`` quantile of sorted values, interpolated linearly as ``np.quantile``'s default does."""
    position = q * (len(ascending) - 1)
    below = int(position)
    above = min(below + 1, len(ascending) - 1)
    return ascending[below] + (ascending[above] - ascending[below]) * (position - below)


def _missing(diff_ns: int, period_ns: int) -> int:
    """Frames missing in a stamp difference of ``diff_ns`` at ``period_ns``."""
    if period_ns <= 0 or diff_ns <= _GAP * period_ns:
        return 0
    return max(1, round(diff_ns / period_ns) - 1)
