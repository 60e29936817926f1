"""A dependency-free progress bar for terminals and logs (redraws in place only on a TTY)."""

from __future__ import annotations

import sys
import time
from typing import TextIO

__all__ = ["ProgressBar"]


class ProgressBar:
    """``label  12/200 [#####-----] 3.1 it/s  <extra>``; call :meth:`update` per step."""

    def __init__(self, total: int, label: str = "", stream: TextIO | None = None, width: int = 24) -> None:
        self.total, self.label, self.width = max(total, 1), label, width
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty()
        self.start = time.perf_counter()
        self._last_log = 0.0

    def update(self, done: int, extra: str = "") -> None:
        """Show progress after ``done`` steps; off a TTY, print at most every 5 s and at the end."""
        now = time.perf_counter()
        rate = done / max(now - self.start, 1e-9)
        filled = int(self.width * done / self.total)
        line = f"{self.label} {done}/{self.total} [{'#' * filled}{'-' * (self.width - filled)}] {rate:.2f} it/s {extra}"
        if self.tty:
            self.stream.write("\r" + line.ljust(100)[:160])
            if done >= self.total:
                self.stream.write("\n")
        elif done >= self.total or now - self._last_log >= 5.0:
            self.stream.write(line + "\n")
            self._last_log = now
        self.stream.flush()
