"""Whether a node is busy with frames or idle and waiting for input, and since when.

Silence of an input is only meaningful while the node waits for it: a node tracking a slow frame
(17 s at 640x480 on a small CPU), or fed by a lockstep player that waits for that frame's pose,
receives nothing meanwhile, and advice to fix remaps would be wrong.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable

__all__ = ["Activity"]

_RATE_FRAMES = 20  # finished frames over which the processing rate is measured


class Activity:
    """Tracks work started and finished; ``is_idle()`` says whether anything is queued or running."""

    def __init__(self, is_idle: Callable[[], bool]) -> None:
        self.is_idle = is_idle
        self.started = time.monotonic()
        self._last_change = self.started  # the last time work started or finished
        self._done: deque[float] = deque(maxlen=_RATE_FRAMES)
        self._lock = threading.Lock()

    def begin(self) -> None:
        """A frame was handed to the workers."""
        now = time.monotonic()
        with self._lock:
            self._last_change = now

    def end(self) -> None:
        """A frame's work finished (a pose or a mapped frame came out)."""
        now = time.monotonic()
        with self._lock:
            self._last_change = now
            self._done.append(now)

    def idle_since(self) -> float | None:
        """When the node last became idle (monotonic s); None while it is busy."""
        if not self.is_idle():
            return None
        with self._lock:
            return self._last_change

    def busy_s(self) -> float:
        """Seconds since the node last finished (or started) a frame while busy; 0 when idle."""
        if self.is_idle():
            return 0.0
        with self._lock:
            return time.monotonic() - self._last_change

    def rate_hz(self) -> float:
        """Frames finished per second over the last ones (0 before two), however slow they are."""
        with self._lock:
            done = list(self._done)
        if len(done) < 2 or done[-1] <= done[0]:
            return 0.0
        return (len(done) - 1) / (done[-1] - done[0])
