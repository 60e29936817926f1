"""``Slam``: one frame in, one :class:`StepResult` out. The ROS nodes, the CLI and the tests all use it.

The parts are built once from the config (the map frame policy, the motion model, the tracker, the
failure guard, the keyframe store) and ``process`` runs the paper's loop with them. ``Slam`` holds
no locks and starts no threads: :mod:`sgs_slam_core.live.pipeline` owns the concurrency.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np
import torch

from sgs_slam_core.config.loader import config_to_dict
from sgs_slam_core.config.schema import SlamConfig
from sgs_slam_core.editing import EditRecord, EditRequest
from sgs_slam_core.errors import BackendUnavailableError, FrameError
from sgs_slam_core.frame import CompactFrame, Frame, compact_labels
from sgs_slam_core.frame_data import FrameTensors
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.kernels import build_kernels
from sgs_slam_core.labels import LabelTable
from sgs_slam_core.mapio.native import MapFile
from sgs_slam_core.profiling import stage
from sgs_slam_core.render.output import RenderOutput
from sgs_slam_core.semantics import SemanticCodec
from sgs_slam_core.slam.densify import densify_frame, scene_radius
from sgs_slam_core.slam.edits import EditLocks
from sgs_slam_core.slam.guard import TrackingGuard, TrackingState
from sgs_slam_core.slam.heap import keep_freed_heap, release_free_heap
from sgs_slam_core.slam.keyframe_store import KeyframeStore
from sgs_slam_core.slam.keyframes import Window, is_keyframe
from sgs_slam_core.slam.label_votes import cast_votes, seen_classes
from sgs_slam_core.slam.late_labels import label_unlabelled
from sgs_slam_core.slam.localization import Localizer
from sgs_slam_core.slam.map_frame import MapFrameChoice, MapFramePolicy
from sgs_slam_core.slam.mapper import MapStats, WindowFrame, map_window
from sgs_slam_core.slam.motion import MotionModel
from sgs_slam_core.slam.outcomes import MapOutcome, StepResult, TrackOutcome
from sgs_slam_core.slam.trackers import build_tracker
from sgs_slam_core.slam.window import choose_window, upload_window

# A Gaussian's features are reset to its voted class once the votes for it lead by this many (a
# splat on a class boundary, its centre on either side from view to view, keeps the features its
# windows gave it while the votes are even). One: live, a Gaussian gets a few label views, and
# waiting for a lead of two left the features a flickered view gave it (room, middle label noise,
# live: 78 against 73 % mIoU; lockstep, clean labels: 90.6 against 91.3 %).
_CONFIDENT_VOTES = 1.0

# Frames a warm-up tracks and maps: the first is only mapped, the second meets the ICP and the
# tracker, the third (without labels) a window of two.
_WARM_UP_FRAMES = 3

__all__ = ["MapOutcome", "Slam", "StepResult", "TrackOutcome", "resolve_device"]

log = logging.getLogger(__name__)


def resolve_device(name: str) -> torch.device:
    """``auto`` -> CUDA when available, else CPU; ``cuda`` without a GPU raises."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise BackendUnavailableError("device 'cuda' requested but torch sees no CUDA GPU")
    return torch.device(name)


def _granted_once(between_iterations: Callable[[], bool] | None) -> Callable[[], bool] | None:
    """``between_iterations`` whose first step was already granted: the first call says True without asking."""
    if between_iterations is None:
        return None
    asked = False

    def between() -> bool:
        nonlocal asked
        if not asked:
            asked = True
            return True
        return between_iterations()

    return between


class Slam:
    """Semantic Gaussian-splatting SLAM (SGS-SLAM) driven one frame at a time.

    The map frame follows ``config.map_frame`` (by default the first camera's frame) unless
    ``initial_c2w`` is given. Every frame must share the first frame's intrinsics and carry depth;
    labels are optional per frame.

    Not thread-safe by itself. :meth:`track` may run beside :meth:`map` (it reads the map
    reference once, and the map is replaced whole, never changed in place); everything else is
    serialised by the caller (:class:`~sgs_slam_core.live.pipeline.SlamPipeline`).
    Creating one sets the process's heap to keep freed memory for reuse between keyframes
    (:func:`~sgs_slam_core.slam.heap.keep_freed_heap`).
    """

    def __init__(
        self, config: SlamConfig, label_table: LabelTable | None = None, initial_c2w: np.ndarray | None = None
    ) -> None:
        self.config = config
        self.device = resolve_device(config.device)
        self.codec = SemanticCodec(config.semantic, label_table or LabelTable.nyu40())
        self.given_c2w = None if initial_c2w is None else np.asarray(initial_c2w, dtype=np.float64)
        keep_freed_heap()  # frame-sized buffers are reused, not faulted in again every frame
        self.reset()

    def prepare(self, announce: Callable[[str], None], sample: Frame | None = None) -> None:
        """Build (or load) the compiled kernels this configuration uses, before anything is timed.

        ``announce`` gets a line for each kernel that must be compiled first (about a minute each).
        With ``render.compile``, ``sample`` (a frame of the coming stream) is tracked and mapped a few
        times by a throwaway SLAM, so ``torch.compile`` traces its graphs at the stream's image size
        now: compiled on first use, live, a frame would wait for seconds and the camera move on.
        """
        self.kernels.prepare(announce)
        if self.config.render.compile and sample is not None:
            h, w = sample.intrinsics.shape
            announce(f"render.compile: compiling for {w}x{h} (seconds; cached on disk for later runs)")
            warm = Slam(self.config, self.codec.table, self.given_c2w)
            for i in range(_WARM_UP_FRAMES):
                labels = sample.labels if i < _WARM_UP_FRAMES - 1 else None  # the graphs without a semantic target
                stamp_ns = sample.stamp_ns + i * 33_000_000
                frame = replace(sample, index=i, stamp_ns=stamp_ns, labels=labels, gt_c2w=None)
                warm.map(frame, warm.track(frame))

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget the map, poses, keyframes and edits (configuration and label table are kept)."""
        c = self.config
        self.initial_c2w = np.eye(4) if self.given_c2w is None else self.given_c2w.copy()
        self.map_frame = MapFramePolicy(c.map_frame)
        self.kernels = build_kernels(c.render, self.device)  # render, losses and steps for this device, chosen once
        self.motion = MotionModel(c.motion, self.initial_c2w, self.kernels.icp, c.features)
        self.tracker = build_tracker(c.tracking, self.kernels)
        self.guard = TrackingGuard(c.guard)
        self.localizer = Localizer(c, self.motion, self.tracker, self.guard, self.kernels)
        self.keyframes = KeyframeStore(c.keyframes)  # capped: the best-covered view leaves
        self.edits = EditLocks()
        self.gaussians = GaussianMap.empty(self.codec.num_channels, device=self.device)
        self.intrinsics: Intrinsics | None = None
        self.trajectory: list[tuple[int, int, np.ndarray]] = []  # (frame index, stamp_ns, c2w)
        self.scene_radius = 1.0
        self.seen_ids: frozenset[int] = frozenset({0})  # replaced, never changed: read beside tracking
        self.rng = np.random.default_rng(c.seed)
        self.torch_rng = torch.Generator(device="cpu").manual_seed(c.seed)
        self.frames_processed = 0
        self.failures = 0
        self._lost_since: int | None = None  # frame index at which the camera was lost, while lost
        self._last_mapped: int | None = None  # index of the last frame mapping ran on
        self._labels_stale = False  # classes last re-decoded at a keyframe (live), mapped since
        self._loaded_trajectory: list[tuple[int, int, np.ndarray]] = []  # a loaded map's history, saved again
        self._loaded_keyframe_poses: list[tuple[int, np.ndarray]] = []  # its keyframes without images
        self._gt_origin: np.ndarray | None = None

    @property
    def num_gaussians(self) -> int:
        """Gaussians in the map."""
        return len(self.gaussians)

    @property
    def last_c2w(self) -> np.ndarray | None:
        """The latest estimated pose."""
        return self.trajectory[-1][2].copy() if self.trajectory else None

    # ------------------------------------------------------------------ the loop
    def process(self, frame: Frame) -> StepResult:
        """Track the frame, then densify, select the window, map, and maybe keep it as a keyframe."""
        tracked = self.track(frame)
        mapped = self.map(frame, tracked)
        return StepResult(tracked.without_tensors(), mapped, self.num_gaussians)  # kept by callers: no images

    def track(self, frame: Frame, newer_frame_waiting: Callable[[], bool] | None = None) -> TrackOutcome:
        """Estimate the pose of ``frame`` against the current map (a run's first frame gets the map frame's pose).

        While the camera is lost (the guard's ``lost_after`` failures in a row) the frame is
        relocalized instead, and its pose is the last accepted one until that succeeds.
        ``newer_frame_waiting`` (live): once it returns True, tracking ends after its minimum steps.
        """
        self._validate(frame)
        t0, index = time.perf_counter(), self.frames_processed
        self._see_labels(frame)
        data, view, result, failure, choice = None, None, None, None, None
        state: TrackingState = self.guard.state
        if index == 0 and len(self.gaussians) == 0:
            choice = self._start(frame)
            c2w = choice.c2w
            view = self.motion.view(frame)  # the next frame's feature reference
        elif self.config.tracking.use_gt_pose:
            c2w = self._gt_in_map_frame(frame.gt_c2w)
        elif len(self.gaussians) == 0:
            c2w = self.trajectory[-1][2].copy() if self.trajectory else self.initial_c2w.copy()  # no map yet
        else:
            data = self._frame_tensors(frame, index)
            view = self.motion.view(frame)
            found = self.localizer.locate(self.gaussians, self.keyframes, frame, data, view, newer_frame_waiting)
            result, failure, state = found.result, found.failure, found.state
            c2w = self.motion.last_c2w if state == "lost" else np.linalg.inv(result.w2c)
        if failure is None and data is None and self.motion.uses_icp:
            data = self._frame_tensors(frame, index)  # the next frame's ICP reference; mapping reuses it
        if state == "relocalized":  # no velocity across the time the camera was lost
            self.motion.restart(frame.stamp_ns, c2w, data, view)
        elif failure is None:  # a failed pose would become the prior, and a lost camera would run away
            self.motion.observe(frame.stamp_ns, c2w, data, view)
        self._append_pose(index, frame.stamp_ns, c2w)
        self.failures += int(failure is not None)
        self._say(index, state, failure)
        elapsed = time.perf_counter() - t0
        return TrackOutcome(index, frame.stamp_ns, c2w, result, failure, elapsed, data, choice, state)

    def _say(self, index: int, state: TrackingState, failure: str | None) -> None:
        """Log when the camera is lost and when it is found again."""
        if state == "lost" and self._lost_since is None:
            self._lost_since = index
            log.warning("tracking lost at frame %d (%s): not mapping until relocalized", index, failure)
        elif state == "relocalized":
            lost = index - (self._lost_since if self._lost_since is not None else index)
            log.warning("relocalized at frame %d after %d frames lost", index, lost)
            self._lost_since = None

    def register(self, frame: Frame, c2w: np.ndarray) -> TrackOutcome:
        """Accept a pose estimated elsewhere (a separate tracking process) for ``frame``."""
        self._validate(frame)
        index = self.frames_processed
        self._see_labels(frame)
        if index == 0:
            self.scene_radius = scene_radius(frame.depth, self.config.mapping.scene_radius_depth_ratio)
        c2w = np.asarray(c2w, dtype=np.float64)
        self.motion.observe(frame.stamp_ns, c2w, None)
        self._append_pose(index, frame.stamp_ns, c2w)
        return TrackOutcome(index, frame.stamp_ns, c2w, None, None, 0.0)

    def map(
        self,
        frame: Frame,
        tracked: TrackOutcome,
        between_iterations: Callable[[], bool] | None = None,
        before_publish: Callable[[], None] | None = None,
    ) -> MapOutcome:
        """Densify, select the window, optimise the map, and keep keyframes (nothing on a failed frame).

        ``between_iterations`` is called before each mapping step; returning False ends the window
        there (the live pipeline: a newer frame waits to be tracked, or to be mapped).
        ``before_publish`` runs before the new map replaces the old one (a side stream's work is
        finished there, so a reader on another stream never meets a map still being computed).
        """
        if tracked.failed:
            return MapOutcome.not_mapped()
        t0, timings = time.perf_counter(), {}
        data = tracked.frame_data or self._frame_tensors(frame, tracked.index)
        data = data.with_ignore(self.edits.ignore_mask(data.labels))  # the locks now: an edit may have come since
        use_sem = frame.labels is not None
        rendering = tracked.result.rendering if tracked.result is not None else None
        rendered = rendering.out if rendering is not None and rendering.gaussians is self.gaussians else None
        with stage("densify"):
            gaussians, added = self._densified(data, frame, tracked.c2w, rendered)
        timings["densify"] = time.perf_counter() - t0
        stats, window = None, None
        if self._mapping_due(tracked.index):
            self._last_mapped = tracked.index
            if between_iterations is None or between_iterations():
                between = _granted_once(between_iterations)
                gaussians, stats, window, use_sem = self._on_window(gaussians, data, frame, tracked, between, timings)
            else:  # live: a job that may not make a single step skips choosing its window (~1.5 ms at 160x120)
                stats = MapStats(0, 0, 0.0, float("nan"))
        if self.votes and frame.labels is not None:
            gaussians = self._voted(gaussians, data, np.linalg.inv(tracked.c2w))
        keyframe = self._keyframe_due(tracked.index)
        gaussians, stale = self._labelled(gaussians, use_sem, keyframe)
        if before_publish is not None:
            before_publish()
        self.gaussians, self._labels_stale = gaussians, stale
        if keyframe:  # freed tensors' pages go back to the OS: the resident size stays as flat as the live data
            self._store_keyframe(frame, tracked)
            release_free_heap()
        timings["map"] = time.perf_counter() - t0
        return MapOutcome(stats, window, keyframe, added, timings["map"], timings)

    def _on_window(
        self,
        gaussians: GaussianMap,
        data: FrameTensors,
        frame: Frame,
        tracked: TrackOutcome,
        between_iterations: Callable[[], bool] | None,
        timings: dict[str, float],
    ) -> tuple[GaussianMap, MapStats, Window, bool]:
        """``gaussians`` optimised on the window chosen for ``frame``: the map, its stats, the window, semantics on."""
        t_sel = time.perf_counter()
        with stage("keyframe_selection"):
            window = choose_window(self.keyframes, data, tracked.c2w, frame.labels, self.config.keyframes, self.rng)
        timings["keyframe_selection"] = time.perf_counter() - t_sel
        frames = upload_window(self.keyframes, window, data, tracked.c2w, self.codec, self.edits)
        # keyframes whose labels came late supervise the semantics of a frame that has none (yet)
        use_sem = frame.labels is not None or any(wf.has_semantic for wf in frames)
        gaussians, stats = self._optimised(gaussians, frames, use_sem, between_iterations)
        return gaussians, stats, window, use_sem

    def fuse_labels(
        self,
        view: CompactFrame,
        labels: np.ndarray,  # [H, W] class ids at the view's size
        between_iterations: Callable[[], bool] | None = None,
        before_publish: Callable[[], None] | None = None,
        optimise: bool = True,
    ) -> MapOutcome:
        """Fuse a label image that came after its view (``view``: as mapped, its pose the mapped one).

        The unlabelled Gaussians the view sees take its classes (:func:`label_unlabelled`), a held
        keyframe of the view keeps the labels for later windows (a view with no labelled keyframe
        within ``keyframes.every`` frames becomes one), and with ``optimise`` the map is optimised on
        the labelled view's window (``between_iterations`` as in :meth:`map`; live, a frame that
        waits skips it: choosing and loading a window costs milliseconds). The classes are
        re-decoded as after a mapped frame (``mapping.refresh_labels*``). Raises :class:`FrameError`
        when the labels do not fit the view.
        """
        t0 = time.perf_counter()
        frame = Frame(view.rgb, view.depth_m, view.intrinsics, labels, view.stamp_ns, None, view.index)
        self._see_labels(frame)
        data = self._frame_tensors(frame, view.index)
        w2c = torch.as_tensor(view.w2c, dtype=torch.float32, device=self.device)
        seen = seen_classes(self.gaussians, data, w2c)  # labelling adds no Gaussian: the votes see the same
        gaussians, _ = label_unlabelled(self.gaussians, data, w2c, seen)  # votes too: no Gaussian keeps zero features
        if self.votes:
            gaussians = self._voted(gaussians, data, view.w2c, seen)
        keyframe = self.keyframes.attach_labels(view.index, labels)
        if not keyframe and not self.keyframes.labelled_near(view.index, self.config.keyframes.every):
            # labels come rarer than keyframes: a labelled view supervises later windows' semantics
            self.keyframes.add(replace(view, labels=compact_labels(labels)))
            keyframe = True
        stats, window = None, None
        if optimise and self.config.mapping.iterations > 0 and len(gaussians):
            c2w = np.linalg.inv(view.w2c)
            window = choose_window(self.keyframes, data, c2w, labels, self.config.keyframes, self.rng)
            frames = upload_window(self.keyframes, window, data, c2w, self.codec, self.edits)
            gaussians, stats = self._optimised(gaussians, frames, True, between_iterations)
        gaussians, stale = self._labelled(gaussians, True, keyframe=False)
        if before_publish is not None:
            before_publish()
        self.gaussians, self._labels_stale = gaussians, stale
        return MapOutcome(stats, window, keyframe, 0, time.perf_counter() - t0)

    def _densified(
        self, data: FrameTensors, frame: Frame, c2w: np.ndarray, rendered: RenderOutput | None
    ) -> tuple[GaussianMap, int]:
        """The map with Gaussians added where it does not explain ``frame`` seen from ``c2w`` [4, 4]; how many.

        ``rendered``: the map already rendered from ``c2w`` (tracking's last rendering), or None.
        """
        d = self.config.densify
        revisit = d.revisit_radius_m is not None and self.keyframes.revisited(
            c2w, data.index, d.revisit_radius_m, d.revisit_angle_deg, d.revisit_min_age
        )
        return densify_frame(
            self.gaussians,
            data,
            frame,
            c2w,
            rendered=rendered,
            revisit=revisit,
            settings=self.config.densify,
            kernels=self.kernels,
            codec=self.codec,
            edits=self.edits,
            generator=self.torch_rng,
        )

    def _optimised(
        self,
        gaussians: GaussianMap,
        window: list[WindowFrame],
        use_semantics: bool,
        between_iterations: Callable[[], bool] | None,
    ) -> tuple[GaussianMap, MapStats]:
        """``gaussians`` after the mapping iterations on ``window``, and what they did."""
        result = map_window(
            gaussians,
            window,
            self.config.mapping,
            kernels=self.kernels,
            scene_radius=self.scene_radius,
            use_semantics=use_semantics,
            rng=self.rng,
            frozen_labels=self.edits.locked_labels,
            between_iterations=between_iterations,
        )
        return result.gaussians, result.stats

    # ------------------------------------------------------------------ edits (serialised by the caller)
    def apply_edit(self, request: EditRequest) -> EditRecord:
        """Edit the live map; the edited classes stay locked (ignored in input, frozen) until undone."""
        self.gaussians, record = self.edits.apply(self.gaussians, request, self.codec.table)
        return record

    def undo_edit(self) -> EditRecord:
        """Revert the last edit, keeping the mapping done since, and unlock its classes."""
        self.gaussians, record = self.edits.undo(self.gaussians)
        return record

    @property
    def locked_labels(self) -> frozenset[int]:
        """Classes locked by edits."""
        return self.edits.locked_labels

    # ------------------------------------------------------------------ map files
    def load_map(self, saved: MapFile, relocalize: bool = False) -> None:
        """Resume in a saved map: the next frame is tracked against it, starting at its last pose.

        ``relocalize``: the camera may have moved since the map was saved (a restart after a
        crash), so the next frames are relocalized against the saved keyframes, as a lost camera's
        are, and nothing is mapped until one is placed. Needs the relocalizer (features on,
        ``guard.lost_after`` > 0) and keyframe images in the file; without them the last pose is
        the start.
        """
        if saved.gaussians.num_semantic != self.codec.num_channels:
            raise FrameError(
                f"the map has {saved.gaussians.num_semantic} semantic channels but semantic.mode={self.codec.mode} "
                f"needs {self.codec.num_channels}"
            )
        self.reset()
        self.edits = EditLocks(frozenset(saved.locked_labels))
        self.codec = self.codec.with_table(saved.label_table)
        self.gaussians = saved.gaussians.to(self.device)
        self.seen_ids = frozenset({0, *saved.seen_labels})
        if saved.trajectory:
            self.initial_c2w = saved.trajectory[-1][2].copy()
            self.motion.resume([c2w for _, _, c2w in saved.trajectory[-2:]])
        # frame indices (keyframe ages) go on from the saved run
        self.frames_processed = saved.frames_processed if saved.frames_processed is not None else len(saved.trajectory)
        self.keyframes = KeyframeStore(self.config.keyframes, saved.keyframe_images)
        with_images = {kf.index for kf in saved.keyframe_images}
        self._loaded_keyframe_poses = [(i, p) for i, p in saved.keyframes if i not in with_images]
        self._loaded_trajectory = list(saved.trajectory)
        if saved.scene_radius is not None:
            self.scene_radius = saved.scene_radius
        self.intrinsics = saved.intrinsics
        if relocalize and self.localizer.relocalizer is not None and saved.keyframe_images:
            self.guard.start_lost()
            self._lost_since = self.frames_processed

    def to_map_file(self, keyframe_images: int = 16) -> MapFile:
        """Everything needed to resume, for :func:`~sgs_slam_core.mapio.save_map`.

        ``keyframe_images``: how many of the most recent keyframes keep their images (0 = poses only).
        """
        return MapFile(
            gaussians=self.gaussians,
            label_table=self.codec.table,
            config=config_to_dict(self.config),
            intrinsics=self.intrinsics,
            keyframes=sorted([*self._loaded_keyframe_poses, *self.keyframe_poses()], key=lambda kp: kp[0]),
            trajectory=[*self._loaded_trajectory, *self.trajectory],
            seen_labels=self.label_candidates(),
            scene_radius=self.scene_radius,
            locked_labels=sorted(self.locked_labels),
            keyframe_images=list(self.keyframes[-keyframe_images:]) if keyframe_images > 0 else [],
            frames_processed=self.frames_processed,
        )

    def set_map(self, gaussians: GaussianMap) -> None:
        """Replace the map (a tracker following a mapper's published map)."""
        if gaussians.num_semantic != self.codec.num_channels:
            raise FrameError(
                f"map has {gaussians.num_semantic} semantic channels, config expects {self.codec.num_channels}"
            )
        self.gaussians = gaussians.to(self.device)

    def use_label_table(self, table: LabelTable) -> None:
        """Label class ids with ``table`` from now on (before the first frame: the map has no classes yet)."""
        if self.frames_processed or len(self.gaussians):
            raise FrameError("the label table can change only before the first frame (reset the map first)")
        self.codec = self.codec.with_table(table)

    # ------------------------------------------------------------------ steps of the loop
    def _start(self, frame: Frame) -> MapFrameChoice:
        """The run's first frame: the map frame, the ground-truth origin and the scene's size."""
        if self.given_c2w is None:
            choice = self.map_frame.choose(frame)
        else:
            choice = MapFrameChoice(self.given_c2w.copy(), "given")
        self.initial_c2w = choice.c2w.copy()
        self.motion.initial_c2w = self.initial_c2w
        self._gt_origin = None if frame.gt_c2w is None else frame.gt_c2w.copy()
        self.scene_radius = scene_radius(frame.depth, self.config.mapping.scene_radius_depth_ratio)
        return choice

    def _mapping_due(self, index: int) -> bool:
        """Map this frame: live mapping skips frames, taking the first past each multiple of ``mapping.every``."""
        every, last = self.config.mapping.every, self._last_mapped
        return (last is None or index // every > last // every) and self.config.mapping.iterations > 0

    def _keyframe_due(self, index: int) -> bool:
        """Whether the mapped frame ``index`` becomes a keyframe."""
        last = self.keyframes[-1].index if self.keyframes else None
        return is_keyframe(index, self.config.keyframes.every, last)

    def _store_keyframe(self, frame: Frame, tracked: TrackOutcome) -> None:
        stored = Frame(frame.rgb, frame.depth, frame.intrinsics, frame.labels, frame.stamp_ns, None, tracked.index)
        self.keyframes.add(CompactFrame.from_frame(stored, np.linalg.inv(tracked.c2w)))

    @property
    def votes(self) -> bool:
        """Whether classes are the labelled views' majority (``semantic.fusion: votes``)."""
        return self.config.semantic.fusion == "votes"

    def _voted(
        self,
        gaussians: GaussianMap,
        data: FrameTensors,
        w2c: np.ndarray,
        seen: tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None = None,  # seen_classes' answer, if made
    ) -> GaussianMap:
        """``gaussians`` with the classes of the labelled view ``data`` (seen from ``w2c`` [4, 4]) voted in."""
        if seen is None:
            seen = seen_classes(gaussians, data, torch.as_tensor(w2c, dtype=torch.float32, device=self.device))
        rows, classes, _ = seen
        locked = torch.tensor(sorted(self.locked_labels), dtype=torch.int64, device=self.device)
        return cast_votes(gaussians, rows, classes, locked)

    def _snapped(self, gaussians: GaussianMap) -> GaussianMap:
        """Labelled Gaussians whose features decode to another class than their votes' reset to that class's target.

        Features that agree with the votes are kept: optimised against the windows, they shade a
        class boundary inside a splat better than the class target would.
        """
        if not len(gaussians):
            return gaussians
        decoded = self.codec.decode(gaussians.semantics, self.label_candidates()).to(self.device)
        wrong = (gaussians.labels > 0) & (decoded != gaussians.labels) & (gaussians.label_weight >= _CONFIDENT_VOTES)
        if self.locked_labels:  # an edit's Gaussians keep what the edit gave them
            locked = torch.tensor(sorted(self.locked_labels), dtype=torch.int64, device=self.device)
            wrong &= ~torch.isin(gaussians.labels, locked)
        targets = self.codec.encode(gaussians.labels).to(gaussians.semantics)  # [N, S]
        return gaussians.with_tensors(semantics=torch.where(wrong[:, None], targets, gaussians.semantics))

    def _labelled(self, gaussians: GaussianMap, use_semantics: bool, keyframe: bool) -> tuple[GaussianMap, bool]:
        """``gaussians`` with classes and features made to agree where due (``mapping.refresh_labels*``); stale?"""
        m = self.config.mapping
        if not (m.refresh_labels and use_semantics):
            return gaussians, self._labels_stale
        if m.refresh_labels_keyframes_only and not keyframe:
            return gaussians, True
        return self._agreed(gaussians), False

    def refresh_labels(self) -> None:
        """Make classes and semantic features agree now where frames were mapped since they last did.

        Regression re-decodes each Gaussian's class from its features; votes reset the features of
        a Gaussian its votes confidently give another class. With ``mapping.refresh_labels_keyframes_only``
        (live runs) that is done at keyframes only; a run's end and a saved map call this.
        """
        if self._labels_stale:
            self.gaussians, self._labels_stale = self._agreed(self.gaussians), False

    def _agreed(self, gaussians: GaussianMap) -> GaussianMap:
        """``gaussians`` with classes and features in agreement, the way ``semantic.fusion`` says."""
        return self._snapped(gaussians) if self.votes else self._refreshed_labels(gaussians)

    def _refreshed_labels(self, gaussians: GaussianMap) -> GaussianMap:
        """Each Gaussian's class decoded again from its semantic features (locked classes neither gain nor lose)."""
        if not len(gaussians):
            return gaussians
        decoded = self.codec.decode(gaussians.semantics, self.label_candidates()).to(self.device)
        locked = self.locked_labels
        if locked:
            ids = torch.tensor(sorted(locked), dtype=torch.int64, device=self.device)
            keep = torch.isin(gaussians.labels, ids) | torch.isin(decoded, ids)
            decoded = torch.where(keep, gaussians.labels, decoded)
        return gaussians.with_tensors(labels=decoded)

    def _see_labels(self, frame: Frame) -> None:
        if frame.labels is not None:
            self.seen_ids = self.seen_ids | {int(i) for i in np.unique(frame.labels)}

    def _append_pose(self, index: int, stamp_ns: int, c2w: np.ndarray) -> None:
        self.trajectory.append((index, stamp_ns, c2w))
        self.frames_processed += 1

    def _validate(self, frame: Frame) -> None:
        if self.intrinsics is None:
            self.intrinsics = frame.intrinsics
        elif frame.intrinsics != self.intrinsics:
            raise FrameError(f"frame intrinsics {frame.intrinsics} differ from the first frame's {self.intrinsics}")
        if frame.valid_depth_fraction == 0:
            raise FrameError("frame has no valid depth: SGS-SLAM needs an RGB-D frame")
        if self.trajectory and frame.stamp_ns < self.trajectory[-1][1]:
            raise FrameError(f"time stamp went backwards: {frame.stamp_ns} < {self.trajectory[-1][1]} ns")

    def _frame_tensors(self, frame: Frame, index: int) -> FrameTensors:
        with stage("upload"):
            data = FrameTensors.from_frame(frame, self.codec, self.device).with_index(index)
            return data.with_ignore(self.edits.ignore_mask(data.labels))

    def _gt_in_map_frame(self, gt_c2w: np.ndarray | None) -> np.ndarray:
        """Ground truth re-expressed so that the first frame's ground truth maps to ``initial_c2w``."""
        if gt_c2w is None:
            raise FrameError("tracking.use_gt_pose is set but the frame has no ground-truth pose")
        if self._gt_origin is None:
            raise FrameError("use_gt_pose needs ground truth on the first frame too")
        return self.initial_c2w @ np.linalg.inv(self._gt_origin) @ gt_c2w

    # ------------------------------------------------------------------ queries
    def label_candidates(self) -> list[int]:
        """Class ids a decoded label may take: every id seen in the input so far."""
        return sorted(self.seen_ids)

    def decode(self, semantic: torch.Tensor) -> torch.Tensor:  # [..., S] -> [...]
        """Class ids from semantic features (rendered or per Gaussian)."""
        return self.codec.decode(semantic, self.label_candidates())

    def decode_image(self, semantic: torch.Tensor) -> torch.Tensor:  # [H, W, S] -> [H, W]
        """Class ids of a rendered image, blends at class boundaries resolved (``SemanticCodec.decode_image``)."""
        return self.codec.decode_image(semantic, self.label_candidates())

    @torch.no_grad()
    def render_view(
        self, c2w: np.ndarray, intrinsics: Intrinsics | None = None, with_semantics: bool = True
    ) -> RenderOutput:
        """Render the current map from a camera-to-world pose (default: the input camera)."""
        k = intrinsics or self.intrinsics
        if k is None:
            raise FrameError("no frame processed yet: give the intrinsics to render with")
        w2c = torch.as_tensor(np.linalg.inv(c2w), dtype=torch.float32, device=self.device)
        return self.kernels.render(self.gaussians, k, w2c, with_semantics=with_semantics)

    def keyframe_poses(self) -> list[tuple[int, np.ndarray]]:
        """(frame index, c2w) of every keyframe, those the store has let go included."""
        return self.keyframes.poses()
