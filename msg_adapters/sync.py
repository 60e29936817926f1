"""An approximate-time synchroniser for N input streams (message_filters is not on PyPI).

Each stream keeps a queue of the ``queue_size`` newest items. When an item arrives, the newest
item of every other stream closest in time to it is taken; if all lie within ``slop_ns`` of each
other (exact equality when ``slop_ns`` is 0) the set is emitted, and every queued item up to those
is removed. Items that leave a queue without being emitted are counted in ``dropped`` (and per
stream in ``dropped_by_input``). Used by the
ROS nodes for live topics and by the bag reader for recorded stamps, so offline and live runs see
the same frame sets.
"""

from __future__ import annotations

from collections import deque
from typing import Any

__all__ = ["ApproximateSync"]


class ApproximateSync:
    """Matches items of ``num_inputs`` streams by time stamp (nanoseconds)."""

    def __init__(self, num_inputs: int, queue_size: int = 10, slop_ns: int = 20_000_000) -> None:
        if num_inputs < 1 or queue_size < 1 or slop_ns < 0:
            raise ValueError(
                f"need num_inputs >= 1, queue_size >= 1, slop_ns >= 0; got {num_inputs}, {queue_size}, {slop_ns}"
            )
        self.queue_size, self.slop_ns = queue_size, slop_ns
        self._queues: list[deque[tuple[int, Any]]] = [deque() for _ in range(num_inputs)]
        self.dropped_by_input = [0] * num_inputs
        self.emitted = 0

    @property
    def dropped(self) -> int:
        """Items of every stream that left their queue without being emitted."""
        return sum(self.dropped_by_input)

    def pending(self, index: int) -> int:
        """Items of stream ``index`` queued, not yet emitted or dropped."""
        return len(self._queues[index])

    @property
    def num_inputs(self) -> int:
        """Number of streams."""
        return len(self._queues)

    def push(self, index: int, stamp_ns: int, item: Any) -> tuple[int, list[Any]] | None:
        """Add an item of stream ``index``; returns ``(stamp of stream 0, items in stream order)`` on a match."""
        queue = self._queues[index]
        queue.append((stamp_ns, item))
        if len(queue) > self.queue_size:
            queue.popleft()
            self.dropped_by_input[index] += 1
        picks = []
        for j, other in enumerate(self._queues):
            if j == index:
                picks.append(len(queue) - 1)
                continue
            if not other:
                return None
            picks.append(min(range(len(other)), key=lambda p, o=other: (abs(o[p][0] - stamp_ns), p)))
        stamps = [self._queues[j][p][0] for j, p in enumerate(picks)]
        if max(stamps) - min(stamps) > self.slop_ns:
            return None
        items = []
        for j, p in enumerate(picks):
            q = self._queues[j]
            for _ in range(p):  # older items of this stream can no longer be matched
                q.popleft()
                self.dropped_by_input[j] += 1
            items.append(q.popleft()[1])
        self.emitted += 1
        return stamps[0], items

    def clear(self) -> None:
        """Forget every queued item (counted as dropped)."""
        for j, q in enumerate(self._queues):
            self.dropped_by_input[j] += len(q)
            q.clear()
