"""A dataset replayed as a live camera would deliver it (``sgs-slam run --realtime [HZ]``).

Frames are released at their recorded stamps (or at ``hz``) into the live pipeline,
:class:`~sgs_slam_core.live.SlamPipeline`, the one the ROS nodes drive: a frame that arrives while
the tracker is still busy replaces the one waiting for it (a camera driver's queue of one) and is
counted as dropped; mapping runs beside tracking, at its own pace, on the newest tracked frame.
Each frame is read from disk just before its release, so reading is not latency; a reader slower
than the camera delays releases, counted as ``late_frames``.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from sgs_slam_core.datasets.base import Dataset
from sgs_slam_core.errors import DatasetError
from sgs_slam_core.frame import Frame
from sgs_slam_core.live import SlamPipeline
from sgs_slam_core.slam.system import MapOutcome, Slam, StepResult, TrackOutcome

__all__ = ["RealtimeOptions", "RealtimeResult", "RealtimeStats", "release_times", "run_realtime"]

log = logging.getLogger(__name__)

_LATE_S = 0.005  # s: a release this much after its time counts as late


@dataclass(frozen=True)
class RealtimeOptions:
    """``hz``: release frames at this rate (Hz); None = at their recorded stamps."""

    hz: float | None = None


@dataclass(frozen=True)
class RealtimeStats:
    """What a live camera at ``realtime_hz`` would have seen the SLAM do."""

    frames_in: int  # released
    frames_tracked: int
    frames_dropped: int  # replaced while tracking was busy (or rejected: see ``bad_frames``)
    frames_mapped: int
    realtime_hz: float  # mean release rate
    wall_s: float  # from the first release until mapping finished
    late_frames: int  # released later than their time (the reader could not keep up)
    bad_frames: int  # rejected by the SLAM (bad depth, stamps going backwards, ...)


@dataclass
class RealtimeResult:
    """Tracked frames in order, each as a :class:`StepResult` (``mapping`` set when it was mapped)."""

    steps: list[StepResult] = field(default_factory=list)
    dataset_indices: list[int] = field(default_factory=list)
    gt_c2w: list[np.ndarray | None] = field(default_factory=list)
    stats: RealtimeStats | None = None


def release_times(stamps_ns: list[int], hz: float | None) -> np.ndarray:  # [N] s after the first release
    """When each frame is released: ``i / hz``, or the recorded stamps relative to the first."""
    n = len(stamps_ns)
    if hz is not None:
        if not hz > 0:
            raise DatasetError(f"--realtime rate must be > 0 Hz, got {hz}")
        return np.arange(n, dtype=np.float64) / hz
    stamps = np.asarray(stamps_ns, dtype=np.float64)
    if n > 1 and (np.any(np.diff(stamps) < 0) or stamps[-1] <= stamps[0]):
        raise DatasetError("the recorded time stamps do not increase: give the camera rate, --realtime HZ")
    return (stamps - stamps[0]) / 1e9


def run_realtime(
    slam: Slam,
    dataset: Dataset,
    hz: float | None,
    on_tracked: Callable[[Frame, StepResult], None] | None = None,
) -> RealtimeResult:
    """Release every frame of ``dataset`` on time into a live pipeline around ``slam``; wait for it.

    ``on_tracked(frame, step)`` is called on this (the releasing) thread for each newly tracked frame,
    between releases (progress display, live viewer); ``step.mapping`` is not known yet there.
    """
    times = release_times(dataset.stamps_ns, hz)
    tracked: dict[int, tuple[Frame, TrackOutcome]] = {}
    mapped: dict[int, MapOutcome] = {}
    news: queue.SimpleQueue[tuple[Frame, TrackOutcome]] = queue.SimpleQueue()
    lock = threading.Lock()

    def on_pose(frame: Frame, outcome: TrackOutcome) -> None:
        with lock:
            tracked[frame.index] = (frame, outcome)
        news.put((frame, outcome))

    def report() -> None:
        while on_tracked is not None and not news.empty():
            frame, outcome = news.get()
            on_tracked(frame, _step(outcome, None, slam.num_gaussians))

    def on_map(frame: Frame, outcome: TrackOutcome, result: MapOutcome) -> None:
        with lock:
            mapped[frame.index] = result

    pipeline = SlamPipeline(slam, lockstep=False, log=log.warning)
    pipeline.pose_listeners.append(on_pose)
    pipeline.map_listeners.append(on_map)
    late = 0
    try:
        start = time.monotonic()
        for i, due in enumerate(times):
            frame = dataset[i]  # read before its release time
            wait = start + due - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            elif -wait > _LATE_S:
                late += 1
            pipeline.submit_frame(frame, time.monotonic())
            report()
        while not pipeline.wait_idle(timeout=0.2):
            report()
        wall_s = time.monotonic() - start
        report()
    finally:
        pipeline.shutdown()
    st = pipeline.stats
    result = RealtimeResult()
    for index in sorted(tracked):
        frame, outcome = tracked[index]
        m = mapped.get(index)
        result.steps.append(_step(outcome, m, slam.num_gaussians))
        result.dataset_indices.append(index)
        result.gt_c2w.append(frame.gt_c2w)
    duration = float(times[-1]) if len(times) > 1 else 0.0
    rate = (len(times) - 1) / duration if duration > 0 else float(hz or 0.0)
    result.stats = RealtimeStats(
        frames_in=st.frames_in, frames_tracked=len(tracked), frames_dropped=st.frames_in - len(tracked),
        frames_mapped=len(mapped), realtime_hz=rate, wall_s=wall_s, late_frames=late, bad_frames=st.errors,
    )  # fmt: skip
    return result


def _step(tr: TrackOutcome, m: MapOutcome | None, gaussians: int) -> StepResult:
    """A tracked frame as a lockstep step would report it (``num_gaussians``: the final map's)."""
    if m is None:
        return StepResult(tr.index, tr.stamp_ns, tr.c2w, tr.tracking, None, None, False, 0, gaussians, tr.failed,
                          tr.failure_reason, tr.time_s, 0.0, {"track": tr.time_s})  # fmt: skip
    return StepResult(tr.index, tr.stamp_ns, tr.c2w, tr.tracking, m.mapping, m.window, m.keyframe, m.added, gaussians,
                      tr.failed, tr.failure_reason, tr.time_s, m.time_s, {"track": tr.time_s, **m.timings})  # fmt: skip
