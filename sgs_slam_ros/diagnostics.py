"""A small /diagnostics publisher (diagnostic_updater is not on PyPI), on the steady clock."""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node

from sgs_slam_ros.messages import header
from sgs_slam_ros.timers import steady_timer

__all__ = ["OK", "WARN", "Diagnostics", "RateMeter"]

OK, WARN = 0, 1  # DiagnosticStatus levels


class RateMeter:
    """Events per second over a sliding window (wall clock)."""

    def __init__(self, window_s: float = 5.0) -> None:
        self.window_s = window_s
        self._times: deque[float] = deque()
        self.last: float | None = None

    def tick(self) -> None:
        """Record one event now."""
        now = time.monotonic()
        self._times.append(now)
        self.last = now

    def rate(self) -> float:
        """Events per second over the window."""
        now = time.monotonic()
        while self._times and now - self._times[0] > self.window_s:
            self._times.popleft()
        return len(self._times) / self.window_s

    def idle_s(self) -> float | None:
        """Seconds since the last event (None if there was none)."""
        return None if self.last is None else time.monotonic() - self.last


class Diagnostics:
    """Publishes one DiagnosticStatus for ``node`` at 1 Hz (wall clock) on /diagnostics."""

    def __init__(self, node: Node, collect: Callable[[], tuple[int, str, dict[str, str]]]) -> None:
        self.node, self.collect = node, collect
        self.pub = node.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.timer = steady_timer(node, 1.0, self.publish)
        self.last_status: DiagnosticStatus | None = None

    def publish(self) -> None:
        """Collect and publish now."""
        level, message, values = self.collect()
        status = DiagnosticStatus(
            level=bytes([level]),
            name=f"sgs_slam: {self.node.get_fully_qualified_name()}",
            message=message,
            hardware_id="sgs_slam_ros",
            values=[KeyValue(key=k, value=v) for k, v in values.items()],
        )
        self.last_status = status
        self.pub.publish(DiagnosticArray(header=header(self.node.get_clock().now().nanoseconds, ""), status=[status]))
