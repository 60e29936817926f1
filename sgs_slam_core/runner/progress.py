"""Progress bars (tqdm): elapsed time, rate, ETA and a live postfix; plain lines off a terminal.

:class:`ProgressBar` is the generic bar (conversion, synthesis). :class:`SlamProgress` follows a
SLAM run frame by frame and shows the live ATE (when the dataset has ground truth), the Gaussian
count, the keyframes held (and the bytes of each) and the tracking failures beside the bar.
"""

from __future__ import annotations

import sys
import time
from typing import TYPE_CHECKING, TextIO

import numpy as np
from tqdm import tqdm

from sgs_slam_core.metrics.trajectory import ate
from sgs_slam_core.slam.footprint import footprint

if TYPE_CHECKING:
    from sgs_slam_core.frame import Frame
    from sgs_slam_core.slam.system import Slam, StepResult

__all__ = ["ProgressBar", "SlamProgress"]


class ProgressBar:
    """``label  40%|####      | 12/30 [00:31<00:47,  2.6s/frame, <extra>]``; call :meth:`update` per step.

    On a terminal tqdm redraws the line in place. Elsewhere (a log file, CI) the same line is
    printed at most every ``log_every_s`` seconds and once at the end, so logs stay readable.
    """

    def __init__(
        self,
        total: int,
        label: str = "",
        stream: TextIO | None = None,
        unit: str = "frame",
        interactive: bool | None = None,
        log_every_s: float = 5.0,
    ) -> None:
        self.total, self.label, self.unit = max(total, 1), label, unit
        self.stream = stream or sys.stderr
        self.interactive = self.stream.isatty() if interactive is None else interactive
        self.log_every_s = log_every_s
        self.start = time.perf_counter()
        self.done = 0
        self._last_log = self.start
        self._closed = False
        self._bar = (
            tqdm(total=self.total, desc=label, unit=unit, file=self.stream, dynamic_ncols=True, smoothing=0.3)
            if self.interactive
            else None
        )

    def update(self, done: int, extra: str = "") -> None:
        """Show progress after ``done`` steps with ``extra`` after the rate (e.g. live metrics)."""
        if self._closed:
            return
        self.done = done
        if self._bar is not None:
            self._bar.set_postfix_str(extra, refresh=False)
            self._bar.update(done - self._bar.n)
            if done >= self.total:
                self.close()
            return
        now = time.perf_counter()
        if done >= self.total or now - self._last_log >= self.log_every_s:
            self.stream.write(self.line(extra, now) + "\n")
            self.stream.flush()
            self._last_log = now
            if done >= self.total:
                self._closed = True

    def line(self, extra: str = "", now: float | None = None) -> str:
        """The current state as one line (tqdm's format: percentage, bar, count, elapsed<ETA, rate)."""
        elapsed = (now or time.perf_counter()) - self.start
        return tqdm.format_meter(
            self.done, self.total, elapsed, ncols=160, prefix=self.label, unit=self.unit, postfix=extra or None
        )

    def close(self) -> None:
        """Finish the line (idempotent)."""
        if self._closed:
            return
        self._closed = True
        if self._bar is not None:
            self._bar.close()


class SlamProgress:
    """A :class:`ProgressBar` over a run's frames showing live ATE, Gaussians and failures.

    The ATE is the RMSE of the aligned camera centres of the frames processed so far (as the
    final metric), recomputed every ``ate_every`` frames (each costs O(frames so far)) and at the
    last frame, once three frames have ground truth.
    """

    def __init__(
        self,
        total: int,
        label: str = "slam",
        stream: TextIO | None = None,
        ate_every: int = 10,
        interactive: bool | None = None,
    ) -> None:
        self.bar = ProgressBar(total, label, stream, interactive=interactive)
        self.ate_every = max(1, ate_every)
        self._est: list[np.ndarray] = []  # [4, 4] c2w of frames with ground truth
        self._gt: list[np.ndarray] = []
        self._ate_cm: float | None = None
        self.frames = 0

    @property
    def ate_cm(self) -> float | None:
        """The latest live ATE RMSE (cm), None before three frames with ground truth."""
        return self._ate_cm

    def log_step(self, frame: Frame, step: StepResult, slam: Slam) -> None:
        """Advance to ``frame`` (its dataset position; skipped frames still count towards the total)."""
        self.frames += 1
        if frame.gt_c2w is not None:
            self._est.append(step.c2w)
            self._gt.append(frame.gt_c2w)
            due = len(self._gt) % self.ate_every == 0 or self.frames >= self.bar.total
            if len(self._gt) >= 3 and due:
                self._ate_cm = 100 * ate(np.stack(self._est), np.stack(self._gt)).rmse
        parts = [f"ATE {self._ate_cm:.2f} cm"] if self._ate_cm is not None else []
        parts.append(footprint(slam).summary())
        if slam.failures:
            parts.append(f"{slam.failures} tracking failures")
        if step.track.lost:
            parts.append("LOST")
        self.bar.update(min(max(frame.index + 1, self.frames), self.bar.total), ", ".join(parts))  # dataset position

    def close(self) -> None:
        """Finish the bar."""
        self.bar.close()
