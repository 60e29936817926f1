"""Live SLAM: a tracking thread and a mapping thread around one :class:`~sgs_slam_core.slam.system.Slam`.

The one place where the SLAM's concurrency lives; the ROS nodes and ``sgs-slam run --realtime``
both drive it. Callers only hand over frames; the work happens on two worker threads.

- **Live** (default): a queue of one, as a live camera's. A frame that arrives while an older one
  still waits for the tracker replaces it (counted in ``stats.dropped_frames``); mapping jobs
  likewise (``stats.dropped_jobs``). The map object is immutable and replaced whole, so the
  tracker always renders one consistent map version. A frame being tracked when a newer one
  arrives ends its tracking after ``slam.tracker.MIN_ITERATIONS`` steps: the camera has moved on.
- **Lockstep**: every frame is kept and frame t is tracked only after frame t-1 is mapped (or, with
  a separate mapping process, after ``ready_to_track`` says its map has arrived).

Live on the CPU, tracking and mapping alternate instead of running their kernels at the same time
(two thread teams on a few cores slow each other down, measured). A tracked frame's mapping job
makes its turn of steps (those that keep the mean over the last ``MAP_FLOOR_JOBS`` jobs at
``live.min_map_steps``; none by default), goes on while no frame waits, and ends (publishing its
map) at the first step boundary after its turn where one does; then that frame is tracked. So
every tracked frame is in the map the next one is tracked against, and a slow machine tracks fewer
frames rather than tracking against a stale map.
Label images may come later than their frames (a segmenter is slower than the camera): with
``late_labels``, mapped views are kept for ``live.label_buffer_s`` seconds, each label image is
matched to the view of its stamp (:class:`~sgs_slam_core.live.label_matcher.LabelMatcher`) and
fused by a mapping job of its own (:meth:`Slam.fuse_labels`), which runs when no frame's job waits;
tracking never waits for labels. A background task (an autosave writing the map) runs its parts in
:meth:`SlamPipeline.background_turn`: on the CPU the tracker waits for a part as for a mapping
step, and a part waits for the frame being tracked.
On CUDA the mapping thread runs on its own stream, beside tracking, and a job ends early when a
newer one waits and it made ``PREEMPT_FRACTION`` of its steps; a mapping process of its own on the
CPU ends a job after one step when a newer one waits.
Two synchronisations make that safe: the mapping thread finishes its stream's work before ``Slam``
publishes a map (``Slam.map``'s ``before_publish``), and tracking reads its result back to the host
before it returns, so no tensor is freed while a kernel of the other thread may still read it.

``Slam`` itself holds no locks: the nodes reach the map, the trajectory and the label table through
this class (:meth:`SlamPipeline.snapshot`, :meth:`SlamPipeline.replace_map`,
:meth:`SlamPipeline.use_label_table`), never by writing ``Slam``'s fields.
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
import traceback
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import numpy as np
import torch

from sgs_slam_core.errors import FrameError, SgsSlamError
from sgs_slam_core.frame import CompactFrame, Frame
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.labels import LabelTable
from sgs_slam_core.live.label_matcher import LabelCounts, LabelMatcher, LateLabels
from sgs_slam_core.mapio import MapFile
from sgs_slam_core.render.output import RenderOutput
from sgs_slam_core.semantics import SemanticCodec
from sgs_slam_core.slam.guard import TrackingState
from sgs_slam_core.slam.system import MapOutcome, Slam, TrackOutcome

__all__ = ["MapJob", "PipelineStats", "SlamPipeline", "SlamSnapshot"]

# With mapping on its own CUDA stream beside tracking, a job ends once it made this fraction of its
# steps and a newer frame waits to be mapped (1 = never early), so a GPU moves on to the newest frame.
PREEMPT_FRACTION = 1 / 3
# Live on the CPU: the mapping steps a job owes keep the mean over this many jobs (its own included)
# at ``live.min_map_steps``.
MAP_FLOOR_JOBS = 10


class _StoppingError(Exception):
    """Raised between mapping steps once the pipeline shuts down (the step in progress is abandoned)."""


@dataclass
class MapJob:
    """A frame to map, with its tracked outcome or a pose from another process."""

    frame: Frame
    tracked: TrackOutcome | None = None
    c2w: np.ndarray | None = None  # [4, 4] registered when ``tracked`` is None
    received_at: float | None = None  # s, monotonic: when the frame arrived


@dataclass(frozen=True)
class SlamSnapshot:
    """What outputs read of the SLAM at one moment; ``last_*`` are None before the first frame."""

    gaussians: GaussianMap
    intrinsics: Intrinsics | None
    codec: SemanticCodec
    label_candidates: tuple[int, ...]  # class ids seen so far (what decoding may return)
    frames_processed: int
    last_stamp_ns: int | None
    last_c2w: np.ndarray | None  # [4, 4]

    def decode(self, semantic: torch.Tensor) -> torch.Tensor:  # [..., S] -> [...] int64
        """Class ids from semantic features (rendered or per Gaussian)."""
        return self.codec.decode(semantic, list(self.label_candidates))

    def decode_image(self, semantic: torch.Tensor) -> torch.Tensor:  # [H, W, S] -> [H, W] int64
        """Class ids of a rendered image, blends at class boundaries resolved (``SemanticCodec.decode_image``)."""
        return self.codec.decode_image(semantic, list(self.label_candidates))


def _preempt_steps(lockstep: bool, share_cpu: bool, device: torch.device, iterations: int) -> int:
    """Live: the steps after which a mapping job ends when a newer job waits (0: it never does).

    Beside tracking on its own stream, ``PREEMPT_FRACTION`` of the iterations. A mapping process of
    its own on the CPU (a mapping_node beside a tracker elsewhere): one, since a step there costs about
    a frame period and the tracker follows the map, which must take in each new frame it can.
    """
    if lockstep or share_cpu:
        return 0
    if device.type == "cpu":
        return 1
    return math.ceil(PREEMPT_FRACTION * iterations)


@dataclass
class PipelineStats:
    """Counters of what happened to the frames handed over (for /diagnostics and metrics.json)."""

    frames_in: int = 0
    tracked: int = 0
    mapped: int = 0
    dropped_frames: int = 0  # replaced before tracking (live mode) or arriving while paused
    dropped_jobs: int = 0  # mapping jobs replaced before mapping (live mode)
    tracking_failures: int = 0  # tracked, but flagged by the failure guard (not mapped)
    tracking_state: TrackingState = "ok"  # of the last tracked frame
    lost_events: int = 0  # times the camera became lost
    relocalizations: int = 0  # times a lost camera was found again
    frames_while_lost: int = 0  # frames tracked while lost (not mapped, pose held)
    tracking_errors: int = 0  # rejected by tracking (bad frame) or failed: no pose
    mapping_errors: int = 0
    map_steps: int = 0  # optimisation steps of the mapping jobs that published a map
    tracking_s: float = 0.0  # time spent tracking the tracked frames (s)
    errors: int = 0  # tracking_errors + mapping_errors + listeners that raised
    last_error: str = ""
    latency_s: deque[float] = field(default_factory=lambda: deque(maxlen=50))  # arrival -> pose (s)
    labels: LabelCounts = field(default_factory=LabelCounts)  # late label images (``late_labels``)
    label_latency_s: deque[float] = field(default_factory=lambda: deque(maxlen=50))  # frame arrival -> labels fused
    snapshot_hold_s: float = 0.0  # how long the last map snapshot (:meth:`SlamPipeline.map_file`) held the workers

    def count_state(self, state: TrackingState) -> None:
        """Count a tracked frame's tracking state (lost and found events, frames lost)."""
        self.lost_events += int(state == "lost" and self.tracking_state != "lost")
        self.relocalizations += int(state == "relocalized")
        self.frames_while_lost += int(state == "lost")
        self.tracking_state = state

    @property
    def tracking_ms_per_frame(self) -> float:
        """Mean time tracking took per tracked frame (ms)."""
        return 1e3 * self.tracking_s / max(self.tracked, 1)

    @property
    def map_steps_per_frame(self) -> float:
        """Mean mapping steps per mapped frame (live: what the time between frames allowed)."""
        return self.map_steps / max(self.mapped, 1)


class SlamPipeline:
    """Feeds frames to ``slam`` on worker threads and reports poses and mapped frames to listeners.

    ``track`` / ``map``: which workers run here (a standalone tracking or mapping node runs one).
    ``ready_to_track(frames_tracked)``: an extra lockstep condition (a remote map has caught up).
    ``late_labels``: label images come on their own (:meth:`submit_labels`), not with the frames.
    How live work shares the machine comes from ``slam.config.live`` (``min_map_steps``),
    ``MAP_FLOOR_JOBS`` and ``PREEMPT_FRACTION``.
    Listeners are called on the worker threads; one that raises is logged and counted.
    """

    def __init__(
        self,
        slam: Slam,
        lockstep: bool,
        track: bool = True,
        map: bool = True,
        log: Callable[[str], None] = print,
        ready_to_track: Callable[[int], bool] | None = None,
        late_labels: bool = False,
    ) -> None:
        self.slam, self.lockstep, self.log = slam, lockstep, log
        self.track_enabled, self.map_enabled = track, map
        self.ready_to_track = ready_to_track
        self.stats = PipelineStats()
        self.pose_listeners: list[Callable[[Frame, TrackOutcome], None]] = []
        self.map_listeners: list[Callable[[Frame, TrackOutcome, MapOutcome], None]] = []
        self.label_listeners: list[Callable[[LateLabels, MapOutcome], None]] = []  # late labels fused
        self.paused = False
        self._frames: deque[tuple[float, Frame]] = deque()
        self._jobs: deque[MapJob] = deque()
        self._label_jobs: deque[LateLabels] = deque()  # matched label images, oldest first
        self._labels = LabelMatcher(slam.config.live.label_buffer_s if late_labels and map else 0.0)
        self.stats.labels = self._labels.counts
        self._cv = threading.Condition()
        self._busy = {"track": False, "map": False, "background": False}  # background: a part of a map write
        self._running = True
        self._finishing = False  # before exit: each mapping job ends at its next step (finish())
        self._map_stream = torch.cuda.Stream(slam.device) if slam.device.type == "cuda" else None
        # live on the CPU: tracking and mapping take turns instead of sharing the cores (see the module doc)
        self._share_cpu = not lockstep and track and map and slam.device.type == "cpu"
        iterations = slam.config.mapping.iterations
        # live on the CPU: the mean steps of a frame's job that its turn keeps up
        self._min_steps = slam.config.live.min_map_steps if self._share_cpu else 0.0
        self._recent_steps: deque[int] = deque(maxlen=MAP_FLOOR_JOBS - 1)  # of the last jobs that asked for steps
        self._turn_steps = 0  # steps the current job makes before a waiting frame is tracked
        self._map_steps = 0  # steps the current mapping job has made
        self._asked = False  # the current job asked for a step (a failed frame or one not due does not)
        self._preempt_steps = _preempt_steps(lockstep, self._share_cpu, slam.device, iterations)
        self._threads = []
        if track:
            self._threads.append(threading.Thread(target=self._track_loop, name="sgs-track", daemon=True))
        if map:
            self._threads.append(threading.Thread(target=self._map_loop, name="sgs-map", daemon=True))
        for t in self._threads:
            t.start()

    # ------------------------------------------------------------------ input
    def submit_frame(self, frame: Frame, received_at: float | None = None) -> None:
        """A synchronised frame from the sensors; ``received_at``: ``time.monotonic()`` of its arrival."""
        with self._cv:
            self.stats.frames_in += 1
            if self.paused:
                self.stats.dropped_frames += 1
                return
            if not self.lockstep and self._frames:
                self._frames.clear()
                self.stats.dropped_frames += 1
            self._frames.append((time.monotonic() if received_at is None else received_at, frame))
            self._cv.notify_all()

    def submit_labels(self, stamp_ns: int, labels: np.ndarray, received_at: float | None = None) -> None:
        """A label image [H, W] (class ids at the processing size) of the frame stamped ``stamp_ns``.

        Fused once that frame is mapped (``late_labels``); without a mapped view of its stamp
        within ``live.label_buffer_s`` it is counted as unmatched.
        """
        with self._cv:
            late = self._labels.add_labels(stamp_ns, labels, time.monotonic() if received_at is None else received_at)
            if late is not None:
                self._label_jobs.append(late)
                self._cv.notify_all()

    def count_dropped(self, frames: int = 1) -> None:
        """Count frames the caller dropped before handing them over (e.g. a pose that never came)."""
        with self._cv:
            self.stats.dropped_frames += frames

    def submit_job(self, job: MapJob) -> None:
        """A frame to map (from the tracking thread, or with a pose from another process)."""
        with self._cv:
            if self.paused:
                self.stats.dropped_frames += 1
                return
            if not self.lockstep and self._jobs:
                self._jobs.clear()
                self.stats.dropped_jobs += 1
            self._jobs.append(job)
            self._cv.notify_all()

    # ------------------------------------------------------------------ workers
    def _mapping_idle(self) -> bool:
        return not self.map_enabled or (not self._jobs and not self._label_jobs and not self._busy["map"])

    def _can_track(self) -> bool:
        if not self.lockstep:
            return self._can_track_live()
        if self.map_enabled and not self._mapping_idle():
            return False
        return self.ready_to_track is None or self.ready_to_track(self.slam.frames_processed)

    def _can_track_live(self) -> bool:
        if self.slam.frames_processed == 0:
            return True
        if not self.map_enabled:  # the map comes from another process: nothing to track against before it
            return self.slam.num_gaussians > 0
        if self.slam.num_gaussians == 0 and not self._mapping_idle():
            return False  # the first frame's Gaussians are being made
        if self._share_cpu:  # never both at once: the last tracked frame's job ends (and publishes) first
            return not (self._jobs or self._busy["map"] or self._busy["background"])
        return True

    def _frame_waiting(self) -> bool:
        """A newer frame waits to be tracked (live: the one being tracked may end early)."""
        with self._cv:
            return bool(self._frames)

    def _in_turn(self) -> bool:
        """The mapping job in progress has not yet made its turn of steps (live on the CPU)."""
        return self._map_steps < self._turn_steps

    def _owed_steps(self) -> int:
        """The steps a frame's job makes before a waiting frame: what lifts the recent mean to the floor."""
        if not self._min_steps:
            return 0
        recent = self._recent_steps
        return max(0, math.ceil(self._min_steps * (len(recent) + 1) - sum(recent)))

    def _track_loop(self) -> None:
        while True:
            with self._cv:
                # every change the tracker waits for notifies; the timeout is a safety net
                self._cv.wait_for(lambda: not self._running or (self._frames and self._can_track()), timeout=0.5)
                if not self._running:
                    return
                if not self._frames or not self._can_track():
                    continue
                received_at, frame = self._frames.popleft()
                self._busy["track"] = True
            try:
                outcome = self.slam.track(frame, None if self.lockstep else self._frame_waiting)
            except Exception as err:
                self._error("tracking", err)
                outcome = None
            with self._cv:
                if outcome is not None:
                    self.stats.tracked += 1
                    self.stats.tracking_s += outcome.time_s
                    self.stats.tracking_failures += int(outcome.failed)
                    self.stats.count_state(outcome.state)
                    self.stats.latency_s.append(time.monotonic() - received_at)
                self._cv.notify_all()
            if outcome is not None:  # still busy: a reset or an exclusive section waits for the hand-over
                if self.map_enabled:  # first: the mapping starts while the pose is published
                    self.submit_job(MapJob(frame, outcome, received_at=received_at))
                self._notify("publishing a pose", self.pose_listeners, frame, outcome)
            with self._cv:
                self._busy["track"] = False
                self._cv.notify_all()

    def _map_loop(self) -> None:
        while True:
            with self._cv:
                self._cv.wait_for(lambda: not self._running or self._jobs or self._label_jobs, timeout=0.5)
                if not self._running:
                    return
                if not self._jobs and not self._label_jobs:
                    continue
                job = self._jobs.popleft() if self._jobs else None  # a frame's job first: the next frame needs it
                late = self._label_jobs.popleft() if job is None else None
                self._busy["map"] = True
                self._map_steps, self._asked = 0, False
                self._turn_steps = self._owed_steps() if job is not None else 0  # labels wait for a free moment
            if late is not None:
                self._fuse(late)
                continue
            result, tracked = None, job.tracked
            try:
                with self._on_map_stream():
                    tracked = job.tracked or self.slam.register(job.frame, job.c2w)
                    result = self.slam.map(job.frame, tracked, self._between_map_steps, self._finish_map_stream)
            except _StoppingError:
                pass  # shutting down: this frame's mapping is abandoned, the map keeps its last version
            except Exception as err:
                self._error("mapping", err)
            view = self._view(job, tracked) if result is not None and tracked is not None else None
            with self._cv:
                self._busy["map"] = False
                self.stats.mapped += int(result is not None)
                self.stats.map_steps += result.stats.iterations if result is not None and result.stats else 0
                if self._asked:
                    self._recent_steps.append(self._map_steps)
                if view is not None:  # with the hand-over: a lockstep tracker waits for its label jobs too
                    self._label_jobs.extend(self._labels.add_view(*view))
                self._cv.notify_all()
            if result is not None and tracked is not None:
                self._notify("publishing the map", self.map_listeners, job.frame, tracked, result)

    def _view(self, job: MapJob, tracked: TrackOutcome) -> tuple[CompactFrame, float] | None:
        """A mapped frame as kept for the label image that may come for it, and its arrival (s); None: not kept."""
        if not self._labels.enabled or tracked.failed or tracked.lost:
            return None
        f = job.frame
        stored = Frame(f.rgb, f.depth, f.intrinsics, None, f.stamp_ns, None, tracked.index)
        view = CompactFrame.from_frame(stored, np.linalg.inv(tracked.c2w))
        return view, time.monotonic() if job.received_at is None else job.received_at

    def _fuse(self, late: LateLabels) -> None:
        """Fuse one matched label image into the map (the mapping thread, busy)."""
        result = None
        try:
            with self._on_map_stream():
                optimise = self.lockstep or not self._frame_waiting()
                result = self.slam.fuse_labels(
                    late.view, late.labels, self._between_map_steps, self._finish_map_stream, optimise
                )
        except _StoppingError:
            pass
        except Exception as err:
            self._error("label fusion", err)
        with self._cv:
            self._busy["map"] = False
            if result is not None:
                self.stats.labels.labels_fused += 1
                self.stats.label_latency_s.append(time.monotonic() - late.view_arrived_at)
            self._cv.notify_all()
        if result is not None:
            self._notify("publishing the labelled map", self.label_listeners, late, result)

    def _between_map_steps(self) -> bool:
        """Before each mapping step: raise when shutting down, return False to end the job here.

        The job ends early live: on its own stream when a newer job waits and this one made its
        share of steps; on the CPU when a frame waits to be tracked and this job made its turn
        (tracking waits for the job to end, so the next frame meets the map with this frame in it).
        A mapping process of its own ends its first job after its share too: the tracker elsewhere
        has no map before it.
        """
        with self._cv:
            if not self._running:
                raise _StoppingError
            self._asked = True
            if self._finishing:
                return False
            if self._share_cpu and self._frames and not self._in_turn():
                return False
            # live, beside a tracker that waits: a newer job, or (mapping alone) a tracker elsewhere
            # that has no map yet and tracks nothing until this job publishes one
            first_awaited = not self.track_enabled and self.stats.mapped == 0
            if self._preempt_steps and (self._jobs or first_awaited) and self._map_steps >= self._preempt_steps:
                return False
            self._map_steps += 1
            return True

    def _finish_map_stream(self) -> None:
        """Before a map made on the mapping stream is shared: its kernels complete first."""
        if self._map_stream is not None:
            self._map_stream.synchronize()

    @contextlib.contextmanager
    def _on_map_stream(self) -> Iterator[None]:
        if self._map_stream is None:
            yield
            return
        with torch.cuda.stream(self._map_stream):
            yield

    def _notify(self, stage: str, listeners: list[Callable[..., None]], *args: object) -> None:
        """Call every listener; one that raises is logged and counted, and the worker goes on.

        (E.g. a publisher whose context Ctrl-C shut down while this thread was still working.)
        """
        for listener in listeners:
            try:
                listener(*args)
            except Exception as err:
                self._error(stage, err)

    def _error(self, stage: str, err: Exception) -> None:
        with self._cv:  # both workers count here
            self.stats.errors += 1
            self.stats.tracking_errors += int(stage == "tracking")
            self.stats.mapping_errors += int(stage == "mapping")
            self.stats.last_error = f"{stage}: {type(err).__name__}: {err}"
        detail = "" if isinstance(err, SgsSlamError) else "\n" + traceback.format_exc()
        self.log(f"{stage} failed on a frame, which is skipped: {err}{detail}")

    # ------------------------------------------------------------------ control
    def idle(self) -> bool:
        """Nothing queued and no worker busy."""
        with self._cv:
            return self._idle()

    def _idle(self) -> bool:
        return not self._frames and not self._jobs and not self._label_jobs and not any(self._busy.values())

    def wait_idle(self, timeout: float) -> bool:
        """Block until idle (or the timeout, s); True when idle."""
        with self._cv:
            return self._cv.wait_for(self._idle, timeout=timeout)

    def finish(self, timeout: float) -> bool:
        """Before exit: the frames in hand tracked and mapped, each mapping job ending at its next step.

        A job's frame is in the map once its Gaussians are added; the steps only refine it, and a
        long window (thousands of steps on a CPU) would hold the exit. Blocks until idle or the
        timeout (s); True when idle. The pipeline keeps working this way until :meth:`shutdown`.
        """
        with self._cv:
            self._finishing = True
            return self._cv.wait_for(self._idle, timeout=timeout)

    def pause(self, paused: bool) -> None:
        """Stop (or resume) accepting frames; queued work is dropped when pausing."""
        with self._cv:
            self.paused = paused
            if paused:
                self.stats.dropped_frames += len(self._frames)
                self._frames.clear()
            self._cv.notify_all()

    def reset(self, timeout: float = 30.0) -> bool:
        """Drop queued work, wait for the workers, and reset the SLAM state; False on timeout (s)."""
        with self._cv:
            self._frames.clear()
            self._jobs.clear()
            if not self._cv.wait_for(lambda: not any(self._busy.values()), timeout=timeout):
                return False
            self._jobs.clear()  # handed over by a frame tracked before the reset
            self.stats.labels.labels_unmatched += len(self._label_jobs)  # their views are gone with the map
            self.stats.labels.labels_matched -= len(self._label_jobs)
            self._label_jobs.clear()
            self._labels.clear()
            self.slam.reset()
            self.stats.tracking_state = "ok"
            self._cv.notify_all()
        return True

    def snapshot(self) -> SlamSnapshot:
        """The map and run state as they are now, for outputs (consistent: the map is replaced whole)."""
        slam = self.slam
        last = slam.trajectory[-1] if slam.trajectory else None
        return SlamSnapshot(
            slam.gaussians,
            slam.intrinsics,
            slam.codec,
            tuple(slam.label_candidates()),
            slam.frames_processed,
            None if last is None else last[1],
            None if last is None else last[2].copy(),
        )

    def render_view(self, snapshot: SlamSnapshot, c2w: np.ndarray) -> RenderOutput:  # c2w [4, 4]
        """Render ``snapshot``'s map from ``c2w`` with its intrinsics and the SLAM's render settings."""
        if snapshot.intrinsics is None:
            raise FrameError("no frame processed yet: nothing to render")
        w2c = torch.as_tensor(np.linalg.inv(c2w), dtype=torch.float32, device=self.slam.device)
        with torch.no_grad():
            return self.slam.kernels.render(snapshot.gaussians, snapshot.intrinsics, w2c)

    def map_file(self, keyframe_images: int = 16, timeout: float = 30.0) -> MapFile:
        """The map, its keyframes and trajectory between two steps of the workers (for saving).

        Holds the workers only while the classes are re-decoded and the parts are gathered: the
        map is immutable, so the snapshot references it. ``TimeoutError`` if they stay busy
        ``timeout`` s.
        """
        with self.exclusive(timeout):
            t0 = time.perf_counter()
            self.slam.refresh_labels()
            snapshot = self.slam.to_map_file(keyframe_images)
            self.stats.snapshot_hold_s = time.perf_counter() - t0
            return snapshot

    @contextlib.contextmanager
    def background_turn(self, timeout: float = 5.0) -> Iterator[None]:
        """Run the body as a part of a background task (a map being written) without slowing tracking.

        Live on the CPU the body starts once no frame is being tracked (or after ``timeout`` s) and
        the tracker waits for it to end, as it waits for a mapping step: on two cores any work beside
        tracking slows it (1.3-1.7x, measured). Elsewhere (lockstep, CUDA) the body just runs.
        """
        if not self._share_cpu:
            yield
            return
        with self._cv:
            self._cv.wait_for(lambda: not self._busy["track"] or not self._running, timeout=timeout)
            self._busy["background"] = True
        try:
            yield
        finally:
            with self._cv:
                self._busy["background"] = False
                self._cv.notify_all()

    def load_map(self, saved: MapFile, relocalize: bool = False, timeout: float = 30.0) -> None:
        """Go on mapping in ``saved`` (queued work and kept views dropped); see :meth:`Slam.load_map`."""
        with self.exclusive(timeout):
            self.stats.dropped_frames += len(self._frames)
            self.stats.dropped_jobs += len(self._jobs)
            self._frames.clear()
            self._jobs.clear()
            self._label_jobs.clear()
            self._labels.clear()
            self.slam.load_map(saved, relocalize)
            self.stats.tracking_state = self.slam.guard.state

    def replace_map(self, gaussians: GaussianMap) -> None:
        """Track against ``gaussians`` from now on (a mapper's map from another process)."""
        self.slam.set_map(gaussians)

    def use_label_table(self, table: LabelTable, timeout: float = 30.0) -> bool:
        """Label with ``table`` when nothing was processed yet; False (table unchanged) once frames were."""
        with self.exclusive(timeout):
            if self.slam.frames_processed or self.slam.num_gaussians:
                return False
            self.slam.use_label_table(table)
            return True

    def wake(self) -> None:
        """Re-check the conditions the workers wait on (e.g. after ``ready_to_track`` may have changed)."""
        with self._cv:
            self._cv.notify_all()

    def exclusive(self, timeout: float = 30.0) -> _Exclusive:
        """Context manager: workers idle and blocked while the body runs (save/load/edit the map)."""
        return _Exclusive(self, timeout)

    def shutdown(self, timeout: float = 120.0) -> None:
        """Stop the worker threads, waiting up to ``timeout`` s for the step each is in.

        Mapping stops at its next iteration; a frame being tracked is finished. A worker left
        running while the interpreter exits can abort the process.
        """
        with self._cv:
            self._running = False
            self._cv.notify_all()
        for t in self._threads:
            t.join(timeout=timeout)


class _Exclusive:
    def __init__(self, pipeline: SlamPipeline, timeout: float) -> None:
        self.p, self.timeout = pipeline, timeout

    def __enter__(self) -> SlamPipeline:
        cv = self.p._cv
        cv.acquire()
        if not cv.wait_for(lambda: not any(self.p._busy.values()), timeout=self.timeout):
            cv.release()
            raise TimeoutError("SLAM workers did not become idle")
        return self.p

    def __exit__(self, *exc: object) -> None:
        self.p._cv.notify_all()
        self.p._cv.release()
