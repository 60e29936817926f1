"""Keeping the map on disk while it is made: a save on request, and autosaves on a thread of their own.

A save has two parts. The *snapshot* (``take``: the map, keyframes and trajectory as they are
between two steps of the SLAM's workers) holds the workers for about a millisecond: the published
map is immutable, so it is referenced, not copied. The *write* (serialising and writing the file)
runs on the saver's thread for autosaves, in turns with tracking on a CPU, and is atomic
(:func:`~sgs_slam_core.fileio.atomic_write`): a crash, a kill or a full disk during a write leaves
the previous file complete. One lock orders the writes, so an older snapshot never replaces a newer
file.

A map that did not change since the last save (or load) is not written again: a node started and
stopped without a camera must not replace yesterday's map with an empty one.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from contextlib import AbstractContextManager
from dataclasses import dataclass
from pathlib import Path

from sgs_slam_core.errors import OutputError, SgsSlamError
from sgs_slam_core.mapio import MapFile, save_map

__all__ = ["MapSaver", "SaveOutcome", "SaveStats"]


@dataclass
class SaveStats:
    """What the saves did so far (for /diagnostics)."""

    saves: int = 0
    failures: int = 0
    last_saved_at: float | None = None  # time.time() of the last successful save (s)
    last_bytes: int = 0  # size of the last file written
    last_snapshot_s: float = 0.0  # how long taking the last snapshot took, the wait for a step boundary included (s)
    last_write_s: float = 0.0  # how long serialising and writing it took (s)
    last_frames: int = 0  # frames processed in the last saved map
    last_error: str = ""  # why the last failed save failed ('' after a success)


@dataclass(frozen=True)
class SaveOutcome:
    """One save: whether it wrote, and a sentence for the log or a service's reply."""

    saved: bool
    message: str


class MapSaver:
    """Writes the map to ``path``: :meth:`save` on the caller's thread, autosaves every ``period_s`` on its own.

    ``take()``: a consistent snapshot of the map (raises :class:`SgsSlamError` or ``TimeoutError``
    when none can be taken). ``turn()``: the context each part of an autosave's write runs in
    (:meth:`SlamPipeline.background_turn`: on the CPU the parts take turns with tracking).
    ``log_error``: one line when saves start failing and one when they work again (not one a
    period); every failure is counted in :attr:`stats`.
    """

    def __init__(
        self,
        path: str | Path,
        take: Callable[[], MapFile],
        period_s: float = 0.0,
        log_info: Callable[[str], None] = print,
        log_error: Callable[[str], None] = print,
        turn: Callable[[], AbstractContextManager[None]] | None = None,
    ) -> None:
        if period_s < 0:
            raise ValueError(f"autosave period must be >= 0 s, got {period_s}")
        self.path, self.period_s = Path(path), period_s
        self._take, self._info, self._error, self._turn = take, log_info, log_error, turn
        self.stats = SaveStats()
        self._write_lock = threading.Lock()  # one write at a time, in the order the snapshots were taken
        self._changed = False  # the map changed since the file was written or read
        self._failing = False
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        if period_s > 0:
            self._thread = threading.Thread(target=self._autosave_loop, name="sgs-autosave", daemon=True)
            self._thread.start()

    def move_to(self, path: str | Path) -> None:
        """Write to ``path`` from now on (the map is not in it yet: the next save writes it)."""
        with self._write_lock:
            self.path, self._changed = Path(path), True

    def held(self) -> threading.Lock:
        """A context manager in which no save runs (e.g. while a map is loaded in place of the current one)."""
        return self._write_lock

    def mark_changed(self) -> None:
        """The map changed (a frame mapped, labels fused, an edit): the next save writes it."""
        self._changed = True

    def mark_saved(self) -> None:
        """The map is the file's (just loaded from it, or reset to nothing new): no save until it changes."""
        self._changed = False

    @property
    def changed(self) -> bool:
        """Whether the map changed since it was last written or read."""
        return self._changed

    def save(self, only_if_changed: bool = False, background: bool = False) -> SaveOutcome:
        """Snapshot the map and write it now (the caller's thread); ``only_if_changed``: skip an unchanged map.

        ``background``: the write takes turns with tracking (``turn``), as autosaves do.
        """
        with self._write_lock:
            if only_if_changed and not self._changed:
                return SaveOutcome(False, f"map unchanged since {self.path} was written or read: not saved")
            self._changed = False  # changes from now on are not in this snapshot
            try:
                t0 = time.perf_counter()
                snapshot = self._take()
                t1 = time.perf_counter()
                size = save_map(self.path, snapshot, self._turn if background else None)
                t2 = time.perf_counter()
            except (SgsSlamError, TimeoutError, OSError) as err:
                self._changed = True  # try again next time
                return self._failed(err)
            s = self.stats
            s.saves, s.last_saved_at, s.last_bytes = s.saves + 1, time.time(), size
            s.last_snapshot_s, s.last_write_s, s.last_frames, s.last_error = t1 - t0, t2 - t1, _frames(snapshot), ""
            message = (
                f"saved {len(snapshot.gaussians)} Gaussians and {s.last_frames} frames to {self.path} "
                f"({size / 2**20:.1f} MiB in {1e3 * (t2 - t0):.0f} ms)"
            )
            if self._failing:
                self._failing = False
                self._info(f"{message}: saving works again")
            return SaveOutcome(True, message)

    def _failed(self, err: BaseException) -> SaveOutcome:
        """Count a failed save; log the first of a run of failures (the previous file is untouched)."""
        reason = str(err) if isinstance(err, OutputError) else f"cannot save {self.path}: {err}"
        self.stats.failures += 1
        self.stats.last_error = reason
        message = f"{reason}; the previous map file is kept"
        if not self._failing:
            self._failing = True
            self._error(message + " (further failures are counted in /diagnostics, not logged)")
        return SaveOutcome(False, message)

    def _autosave_loop(self) -> None:
        while not self._stop.wait(self.period_s):
            self.save(only_if_changed=True, background=True)

    def close(self, timeout: float = 30.0) -> None:
        """Stop autosaving; a write in progress is finished (up to ``timeout`` s)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=timeout)


def _frames(m: MapFile) -> int:
    return m.frames_processed if m.frames_processed is not None else len(m.trajectory)
