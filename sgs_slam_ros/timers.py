"""Timers that run on the steady clock, and outputs published after work was done.

ROS timers follow the node's clock, which under ``use_sim_time`` is the replayed ``/clock``: when a
short bag ends, that clock stops and every timer with it (renders, clouds, diagnostics froze). The
nodes' periodic work therefore runs on the steady clock, and outputs are published when there is
something new (a mapped frame, an edit), at most at their rate.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.timer import Timer

__all__ = ["Throttled", "steady_timer"]


def steady_timer(node: Node, period_s: float, callback: Callable[[], None]) -> Timer:
    """A timer of ``node`` on the steady (wall) clock, whatever ``use_sim_time`` says."""
    return node.create_timer(period_s, callback, clock=Clock(clock_type=ClockType.STEADY_TIME))


class Throttled:
    """Calls ``publish`` after :meth:`mark`, at most ``rate_hz`` times a second (0 = never by itself).

    ``publish`` returns whether it published (``count`` counts those); one that did not (no
    subscriber yet, nothing to show) leaves the request pending for the next tick.

    Each :meth:`mark` asks for one publication of the newest state; marks that arrive faster than
    the rate are merged. :meth:`set_rate` applies a new rate at once (a live parameter change).
    """

    def __init__(self, node: Node, rate_hz: float, publish: Callable[[], bool]) -> None:
        self.node, self.publish = node, publish
        self.rate_hz = 0.0
        self.count = 0  # publications so far
        self._pending = False
        self._lock = threading.Lock()
        self._timer: Timer | None = None
        self.set_rate(rate_hz)

    def mark(self) -> None:
        """Something new to publish."""
        with self._lock:
            self._pending = True

    def set_rate(self, rate_hz: float) -> None:
        """Publish at most ``rate_hz`` times a second from now on (0 = off)."""
        if self._timer is not None:
            self.node.destroy_timer(self._timer)
            self._timer = None
        self.rate_hz = float(rate_hz)
        if self.rate_hz > 0:
            self._timer = steady_timer(self.node, 1.0 / self.rate_hz, self._tick)

    def _tick(self) -> None:
        with self._lock:
            pending, self._pending = self._pending, False
        if pending:
            self._publish()

    def now(self) -> None:
        """Publish immediately (a pending request is served by it)."""
        with self._lock:
            self._pending = False
        self._publish()

    def _publish(self) -> None:
        published = self.publish()
        self.count += int(published)
        if not published:
            with self._lock:
                self._pending = True
