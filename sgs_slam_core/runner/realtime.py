"""A dataset replayed as a live camera would deliver it (``sgs-slam run --realtime [HZ]``).

The first frame initialises the map (it is tracked and mapped before anything else, as a robot
waits for its SLAM to be ready before it moves); from then on frames are released at their
recorded stamps (or at ``hz``) into the live pipeline,
:class:`~sgs_slam_core.live.SlamPipeline`, the one the ROS nodes drive: a frame that arrives while
the tracker is still busy replaces the one waiting for it (a camera driver's queue of one) and is
counted as dropped; mapping runs beside tracking, at its own pace, on the newest tracked frame.
A camera delivers decoded images, so the frames are decoded before the camera's clock starts, as
many as fit in ``RealtimeOptions.preload_mb``: decoding image files beside the SLAM would take
cores that a robot's SLAM has to itself. Frames past that budget are read just before their
release; a reader slower than the camera delays releases, counted as ``late_frames``.

With ``RealtimeOptions.labels`` the frames go in without their labels, and a segmenter's stream is
reproduced beside them (:mod:`~sgs_slam_core.runner.label_stream`): the label images of frames about
``1 / rate`` apart, each released ``delay`` after its frame, fused into the map when they come.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from sgs_slam_core.datasets.base import Dataset
from sgs_slam_core.errors import ConfigError, DatasetError, FrameError
from sgs_slam_core.frame import Frame
from sgs_slam_core.live import SlamPipeline
from sgs_slam_core.runner.label_stream import LabelStream, label_releases
from sgs_slam_core.slam.outcomes import MapOutcome, StepResult, TrackOutcome
from sgs_slam_core.slam.system import Slam

__all__ = ["RealtimeOptions", "RealtimeResult", "RealtimeStats", "release_times", "run_realtime"]

log = logging.getLogger(__name__)

_LATE_S = 0.005  # s: a release this much after its time counts as late


@dataclass(frozen=True)
class RealtimeOptions:
    """``hz``: release frames at this rate (Hz); None = at their recorded stamps.

    ``preload_mb``: decoded frames (MiB) read before the camera's clock starts; 0 = each frame is
    read just before its release. ``labels``: the label images come as a segmenter's stream, apart
    from the frames (None: each frame carries its own).
    """

    hz: float | None = None
    preload_mb: float = 1024.0
    labels: LabelStream | None = None

    def __post_init__(self) -> None:
        if not self.preload_mb >= 0:
            raise ConfigError(f"the realtime preload must be >= 0 MiB, got {self.preload_mb}")


@dataclass(frozen=True)
class RealtimeStats:
    """What a live camera at ``realtime_hz`` would have seen the SLAM do."""

    frames_in: int  # in the input (released, or unreadable)
    frames_tracked: int
    frames_dropped: int  # replaced while tracking was busy
    frames_mapped: int
    realtime_hz: float  # mean release rate
    wall_s: float  # from the camera's start (after initialisation) until mapping finished
    late_frames: int  # released later than their time (the reader could not keep up)
    bad_frames: int  # unreadable, or rejected by the SLAM (bad depth, stamps going backwards, ...)
    preloaded_frames: int = 0  # read before the camera's clock started (unreadable ones included)
    labels_in: int | None = None  # label images released (None: frames carried their labels)
    labels_fused: int | None = None
    labels_unmatched: int | None = None  # no mapped view of their stamp
    label_latency_ms: float | None = None  # median, from a frame's release to its labels fused


@dataclass
class RealtimeResult:
    """Tracked frames in order, each as a :class:`StepResult` (``mapping`` set when it was mapped)."""

    stats: RealtimeStats
    steps: list[StepResult] = field(default_factory=list)
    dataset_indices: list[int] = field(default_factory=list)
    gt_c2w: list[np.ndarray | None] = field(default_factory=list)
    interrupted: bool = False  # ``should_stop`` ended the replay before the last frame
    first_skip: str = ""  # why the first rejected or unreadable frame was skipped


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
    options: RealtimeOptions,
    on_tracked: Callable[[Frame, StepResult], None] | None = None,
    should_stop: Callable[[], bool] = lambda: False,
    announce: Callable[[str], None] = log.info,
) -> RealtimeResult:
    """Release every frame of ``dataset`` on time into a live pipeline around ``slam``; wait for it.

    ``on_tracked(frame, step)`` is called on this (the releasing) thread for each newly tracked frame,
    between releases (progress display, live viewer); ``step.map`` is not known yet there.
    ``should_stop()`` is asked while preloading and before each release: True ends the replay (the
    frames in flight finish). A frame that cannot be read is skipped and counted with the frames
    the SLAM rejects. ``announce(line)`` tells the user about the decoding before the clock starts.
    """
    times = release_times(dataset.stamps_ns, options.hz)
    replay = _Replay(slam, dataset, on_tracked, options.labels)
    if options.preload_mb > 0:
        announce(f"decoding frames before the camera starts (up to {options.preload_mb:g} MiB)")
        replay.preload(len(times), int(options.preload_mb * 2**20), should_stop)
    return replay.run(times, options.hz, should_stop)


class _Replay:
    """One realtime replay: the pipeline's listeners collect outcomes, ``run`` releases the frames."""

    def __init__(
        self,
        slam: Slam,
        dataset: Dataset,
        on_tracked: Callable[[Frame, StepResult], None] | None,
        labels: LabelStream | None = None,
    ) -> None:
        self.slam, self.dataset, self.on_tracked, self.label_stream = slam, dataset, on_tracked, labels
        self.held_labels: dict[int, tuple[int, np.ndarray]] = {}  # frame index -> (stamp ns, labels) until due
        # by dataset index: ground truth c2w [4, 4] (or None) and the outcome without its tensors
        # (the mapper still has those; kept here they would add a frame's images per tracked frame)
        self.tracked: dict[int, tuple[np.ndarray | None, TrackOutcome]] = {}
        self.mapped: dict[int, MapOutcome] = {}
        self.news: queue.SimpleQueue[tuple[Frame, TrackOutcome]] = queue.SimpleQueue()  # not yet reported
        self.errors: list[str] = []
        self.lock = threading.Lock()
        self.late, self.unreadable, self.first_skip = 0, 0, ""
        self.started = False  # the camera clock runs (after initialisation)
        self.ahead: dict[int, Frame | None] = {}  # decoded before the clock started (None: unreadable)
        self.preloaded = 0

    def on_pose(self, frame: Frame, outcome: TrackOutcome) -> None:  # tracking thread
        with self.lock:
            self.tracked[frame.index] = (frame.gt_c2w, outcome.without_tensors())
        self.news.put((frame, outcome))

    def on_map(self, frame: Frame, outcome: TrackOutcome, result: MapOutcome) -> None:  # mapping thread
        with self.lock:
            self.mapped[frame.index] = result

    def on_error(self, line: str) -> None:
        self.errors.append(next(iter(line.splitlines()), ""))  # the message; a traceback only in the log
        log.warning(line)

    def report(self) -> None:
        """Hand the newly tracked frames to ``on_tracked`` (on the releasing thread)."""
        while self.on_tracked is not None and not self.news.empty():
            frame, outcome = self.news.get()
            self.on_tracked(frame, StepResult(outcome, MapOutcome.not_mapped(), self.slam.num_gaussians))

    def preload(self, n: int, budget_bytes: int, should_stop: Callable[[], bool]) -> None:
        """Decode frames 0, 1, ... of ``n`` into ``ahead`` while they fit in ``budget_bytes``."""
        used = 0
        for i in range(n):
            if should_stop():
                return
            frame = self.read(i)
            used += 0 if frame is None else frame.nbytes
            if used > budget_bytes:
                return  # read again at its release, so the budget holds
            self.ahead[i] = frame
            self.preloaded += 1

    def read(self, i: int) -> Frame | None:
        """Frame ``i``, or None (counted, logged) when it cannot be read."""
        try:
            return self.dataset[i]
        except (DatasetError, FrameError) as err:
            self.unreadable += 1
            self.first_skip = self.first_skip or f"frame {i}: {err}"
            log.warning("frame %d skipped: %s", i, err)
            return None

    def run(self, times: np.ndarray, hz: float | None, should_stop: Callable[[], bool]) -> RealtimeResult:
        late_labels = self.label_stream is not None
        pipeline = SlamPipeline(self.slam, lockstep=False, log=self.on_error, late_labels=late_labels)
        pipeline.pose_listeners.append(self.on_pose)
        pipeline.map_listeners.append(self.on_map)
        labels_due = deque(label_releases(times, self.label_stream)) if self.label_stream is not None else deque()
        labelled = {i for _, i in labels_due}
        interrupted = False
        try:
            start = time.monotonic()
            for i, due in enumerate(times):
                if should_stop():
                    interrupted = True
                    break
                # popped: preloaded frames leave memory as they are released
                frame = self.ahead.pop(i) if i in self.ahead else self.read(i)  # before its release time
                if frame is None:
                    continue
                if late_labels:
                    frame = self.strip_labels(i, frame, i in labelled)
                if self.tracked and i > 0 and not self.started:  # initialised: the camera starts moving now
                    start, self.started = time.monotonic() - due, True
                self.release_labels(pipeline, labels_due, start, due)
                wait = start + due - time.monotonic()
                if wait > 0:
                    time.sleep(wait)
                elif -wait > _LATE_S:
                    self.late += 1
                pipeline.submit_frame(frame, time.monotonic())
                self.release_labels(pipeline, labels_due, start, due, inclusive=True)
                if not self.started and not self.tracked:  # initialisation: the first frame is tracked and mapped
                    pipeline.wait_idle(timeout=600.0)
                self.report()
            self.release_labels(pipeline, labels_due, start, float("inf"), inclusive=True)
            while not pipeline.wait_idle(timeout=0.2):
                self.report()
            wall_s = time.monotonic() - start
            self.report()
        finally:
            pipeline.shutdown()
        self.slam.refresh_labels()  # the workers are stopped: the classes as of the last mapped frame
        result = RealtimeResult(
            self._stats(pipeline, times, hz, wall_s),
            interrupted=interrupted,
            first_skip=self.first_skip or (self.errors[0] if self.errors else ""),
        )
        for index in sorted(self.tracked):
            gt_c2w, outcome = self.tracked[index]
            mapped = self.mapped.get(index, MapOutcome.not_mapped())
            result.steps.append(StepResult(outcome, mapped, self.slam.num_gaussians))  # the final map's size
            result.dataset_indices.append(index)
            result.gt_c2w.append(gt_c2w)
        return result

    def strip_labels(self, i: int, frame: Frame, labelled: bool) -> Frame:
        """``frame`` without its labels; those of a frame the segmenter labels are held until due."""
        if labelled and frame.labels is not None:
            self.held_labels[i] = (frame.stamp_ns, frame.labels)
        return replace(frame, labels=None)

    def release_labels(
        self, pipeline: SlamPipeline, due: deque[tuple[float, int]], start: float, until: float, inclusive: bool = False
    ) -> None:
        """Release the label images due before ``until`` (s after ``start``; or at it), each at its time."""
        while due and (due[0][0] < until or (inclusive and due[0][0] <= until)):
            at, i = due.popleft()
            held = self.held_labels.pop(i, None)
            if held is None:
                continue  # the frame was unreadable or has no labels
            wait = start + at - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            pipeline.submit_labels(held[0], held[1], time.monotonic())

    def _stats(self, pipeline: SlamPipeline, times: np.ndarray, hz: float | None, wall_s: float) -> RealtimeStats:
        st = pipeline.stats
        labels = st.labels if self.label_stream is not None else None
        latency = float(np.median(st.label_latency_s)) * 1e3 if st.label_latency_s else None
        mapped = sum(m.stats is not None for m in self.mapped.values())  # optimised, as in lockstep
        duration = float(times[-1]) if len(times) > 1 else 0.0
        rate = (len(times) - 1) / duration if duration > 0 else float(hz or 0.0)
        return RealtimeStats(
            frames_in=st.frames_in + self.unreadable,
            frames_tracked=len(self.tracked),
            frames_dropped=st.frames_in - len(self.tracked) - st.tracking_errors,
            frames_mapped=mapped,
            realtime_hz=rate,
            wall_s=wall_s,
            late_frames=self.late,
            bad_frames=self.unreadable + st.tracking_errors,
            preloaded_frames=self.preloaded,
            labels_in=None if labels is None else labels.labels_in,
            labels_fused=None if labels is None else labels.labels_fused,
            labels_unmatched=None if labels is None else labels.labels_unmatched,
            label_latency_ms=latency,
        )
