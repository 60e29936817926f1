"""``Slam``: one frame in, one :class:`StepResult` out. The ROS nodes, the CLI and the tests all use it."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from sgs_slam_core.config.loader import config_to_dict
from sgs_slam_core.config.schema import SlamConfig
from sgs_slam_core.editing import EditRecord, EditRequest
from sgs_slam_core.errors import BackendUnavailableError, FrameError
from sgs_slam_core.frame import Frame
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.geometry.se3 import se3_inverse
from sgs_slam_core.kernels import build_kernels
from sgs_slam_core.labels import LabelTable
from sgs_slam_core.mapio.native import MapFile
from sgs_slam_core.profiling import stage
from sgs_slam_core.render.output import RenderOutput
from sgs_slam_core.semantics import SemanticCodec
from sgs_slam_core.slam.densify import densify_mask, gaussians_from_pixels, over_budget, scene_radius
from sgs_slam_core.slam.edits import EditLocks
from sgs_slam_core.slam.frame_data import CompactFrame, FrameTensors, resize_arrays
from sgs_slam_core.slam.guard import TrackingGuard
from sgs_slam_core.slam.icp_init import IcpInit
from sgs_slam_core.slam.keyframe_store import KeyframeStore
from sgs_slam_core.slam.keyframes import Window, is_keyframe, select_window
from sgs_slam_core.slam.mapper import MapResult, MapStats, WindowFrame, map_window
from sgs_slam_core.slam.pose import predict_constant_velocity
from sgs_slam_core.slam.tracker import TrackResult
from sgs_slam_core.slam.trackers import build_tracker

__all__ = ["MapOutcome", "Slam", "StepResult", "TrackOutcome", "resolve_device"]


def resolve_device(name: str) -> torch.device:
    """``auto`` -> CUDA when available, else CPU; ``cuda`` without a GPU raises."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise BackendUnavailableError("device 'cuda' requested but torch sees no CUDA GPU")
    return torch.device(name)


@dataclass(frozen=True)
class TrackOutcome:
    """The pose of one frame (tracked, ground truth, or registered from elsewhere)."""

    index: int
    stamp_ns: int
    c2w: np.ndarray  # [4, 4]
    tracking: TrackResult | None
    failure_reason: str | None
    time_s: float
    frame_data: FrameTensors | None = field(default=None, repr=False, compare=False)  # reused by map()

    @property
    def failed(self) -> bool:
        """True when the failure guard rejected the frame."""
        return self.failure_reason is not None


@dataclass(frozen=True)
class MapOutcome:
    """What mapping did with one frame."""

    mapping: MapStats | None  # None when not mapped (the map itself is the Slam's, not kept per frame)
    window: Window | None
    keyframe: bool
    added: int
    time_s: float
    timings: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class StepResult:
    """What happened to one frame."""

    index: int  # frame counter of this Slam (0 = first processed frame)
    stamp_ns: int
    c2w: np.ndarray  # [4, 4] estimated camera-to-world pose (map frame)
    tracking: TrackResult | None  # None for the first frame (and with use_gt_pose)
    mapping: MapStats | None  # None when not mapped (failure, or not a mapping frame)
    window: Window | None
    keyframe: bool
    added: int  # Gaussians added by initialisation / densification
    num_gaussians: int
    tracking_failed: bool = False
    failure_reason: str | None = None
    track_time_s: float = 0.0
    map_time_s: float = 0.0  # densification + mapping
    timings: dict[str, float] = field(default_factory=dict)


class Slam:
    """Semantic Gaussian-splatting SLAM (SGS-SLAM) driven one frame at a time.

    The map frame is the first camera's frame unless ``initial_c2w`` is given. Every frame must
    share the first frame's intrinsics and carry depth; labels are optional per frame.

    Thread safety: :meth:`track` may run beside :meth:`map` (it reads an immutable map snapshot);
    everything that replaces the map (:meth:`map`, edits, :meth:`load_map`, :meth:`set_map`) is
    serialised, so an edit is never overwritten by a mapping step that started before it.
    """

    def __init__(
        self, config: SlamConfig, label_table: LabelTable | None = None, initial_c2w: np.ndarray | None = None
    ) -> None:
        self.config = config
        self.device = resolve_device(config.device)
        self.codec = SemanticCodec(config.semantic, label_table or LabelTable.nyu40())
        self.initial_c2w = np.eye(4) if initial_c2w is None else np.asarray(initial_c2w, dtype=np.float64)
        self._mutate = threading.RLock()
        self.reset()

    def prepare(self, announce: Callable[[str], None]) -> None:
        """Build (or load) the compiled kernels this configuration uses, before anything is timed.

        ``announce`` gets a line for each kernel that must be compiled first (about a minute each).
        """
        self.kernels.prepare(announce)

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget the map, poses, keyframes and edits (configuration and label table are kept)."""
        self._lock = threading.RLock()
        self.edits = EditLocks()
        self.gaussians = GaussianMap.empty(self.codec.num_channels, device=self.device)
        self.intrinsics: Intrinsics | None = None
        self.keyframes = KeyframeStore(self.config.keyframes)  # capped: the best-covered view leaves
        self.trajectory: list[tuple[int, int, np.ndarray]] = []  # (frame index, stamp_ns, c2w)
        self.scene_radius = 1.0
        self.seen_ids: set[int] = {0}
        self.guard = TrackingGuard(self.config.guard)
        self.rng = np.random.default_rng(self.config.seed)
        self.torch_rng = torch.Generator(device="cpu").manual_seed(self.config.seed)
        self.frames_processed = 0
        self._last_mapped: int | None = None  # index of the last frame mapping ran on
        self.failures = 0
        self._resumed_poses: list[np.ndarray] = []  # last two c2w of a loaded map (motion prior)
        self._loaded_trajectory: list[tuple[int, int, np.ndarray]] = []  # a loaded map's history, saved again
        self._loaded_keyframe_poses: list[tuple[int, np.ndarray]] = []  # its keyframes without images
        self._gt_origin: np.ndarray | None = None
        self._min_interval_ns: int | None = None  # shortest stamp gap between two tracked frames
        icp = self.config.tracking.icp
        self._icp = None if icp is None else IcpInit(icp, self.config.tracking.icp_min_inliers)
        self.kernels = build_kernels(self.config.render, self.device)
        self.tracker = build_tracker(self.config.tracking, self.kernels)

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
        """Track, densify, select keyframes, map, and maybe keep the frame as a keyframe."""
        tracked = self.track(frame)
        mapped = self.map(frame, tracked)
        timings = {"track": tracked.time_s, **mapped.timings}
        return StepResult(tracked.index, tracked.stamp_ns, tracked.c2w, tracked.tracking, mapped.mapping, mapped.window,
                          mapped.keyframe, mapped.added, self.num_gaussians, tracked.failed, tracked.failure_reason,
                          tracked.time_s, mapped.time_s, timings)  # fmt: skip

    def track(self, frame: Frame, newer_frame_waiting: Callable[[], bool] | None = None) -> TrackOutcome:
        """Estimate the pose of ``frame`` against the current map (frame 0 gets ``initial_c2w``).

        ``newer_frame_waiting`` (live): once it returns True, tracking ends after its minimum steps.
        """
        self._validate(frame)
        t0 = time.perf_counter()
        index = self.frames_processed
        with self._lock:
            if frame.labels is not None:
                self.seen_ids.update(int(i) for i in np.unique(frame.labels))
        tracking: TrackResult | None = None
        failure: str | None = None
        data = None
        if index == 0 and len(self.gaussians) == 0:
            c2w = self.initial_c2w.copy()
            self._gt_origin = None if frame.gt_c2w is None else frame.gt_c2w.copy()
            self.scene_radius = scene_radius(frame.depth, self.config.mapping.scene_radius_depth_ratio)
        elif self.config.tracking.use_gt_pose:
            if frame.gt_c2w is None:
                raise FrameError("tracking.use_gt_pose is set but the frame has no ground-truth pose")
            c2w = self._gt_in_map_frame(frame.gt_c2w)
        elif len(self.gaussians) == 0:
            c2w = self.trajectory[-1][2].copy() if self.trajectory else self.initial_c2w.copy()  # no map yet
        else:
            data = self._frame_tensors(frame)
            tracking = self._track(data, frame, newer_frame_waiting)
            c2w = np.linalg.inv(tracking.w2c)
            failure = self.guard.check(tracking.depth_residual_m, tracking.loss_per_pixel, tracking.valid_fraction)
        if self._icp is not None and failure is None:  # the next frame's ICP reference
            data = self._frame_tensors(frame) if data is None else data  # mapping reuses it
            self._icp.remember(torch.where(data.valid, data.depth, 0.0), frame.intrinsics, c2w)
        if self.trajectory and frame.stamp_ns > self.trajectory[-1][1]:
            gap = frame.stamp_ns - self.trajectory[-1][1]
            self._min_interval_ns = gap if self._min_interval_ns is None else min(gap, self._min_interval_ns)
        self.trajectory.append((index, frame.stamp_ns, c2w))
        self.frames_processed += 1
        if failure is not None:
            self.failures += 1
        return TrackOutcome(index, frame.stamp_ns, c2w, tracking, failure, time.perf_counter() - t0, data)

    def register(self, frame: Frame, c2w: np.ndarray) -> TrackOutcome:
        """Accept a pose estimated elsewhere (a separate tracking process) for ``frame``."""
        self._validate(frame)
        index = self.frames_processed
        with self._lock:
            if frame.labels is not None:
                self.seen_ids.update(int(i) for i in np.unique(frame.labels))
        if index == 0:
            self.scene_radius = scene_radius(frame.depth, self.config.mapping.scene_radius_depth_ratio)
        c2w = np.asarray(c2w, dtype=np.float64)
        self.trajectory.append((index, frame.stamp_ns, c2w))
        self.frames_processed += 1
        return TrackOutcome(index, frame.stamp_ns, c2w, None, None, 0.0)

    def map(
        self, frame: Frame, tracked: TrackOutcome, between_iterations: Callable[[], bool] | None = None
    ) -> MapOutcome:
        """Densify, select the window, optimise the map, and keep keyframes (nothing on a failed frame).

        ``between_iterations`` is called before each mapping step; returning False ends the window
        there (the live pipeline: a newer frame waits to be tracked, or to be mapped).
        """
        if tracked.failed:
            return MapOutcome(None, None, False, 0, 0.0)
        with self._mutate:
            return self._map_frame(frame, tracked, between_iterations)

    def _map_frame(
        self, frame: Frame, tracked: TrackOutcome, between_iterations: Callable[[], bool] | None = None
    ) -> MapOutcome:
        t0 = time.perf_counter()
        index, c2w = tracked.index, tracked.c2w
        if tracked.frame_data is None:
            data = self._frame_tensors(frame)
        else:
            data = tracked.frame_data
            data.ignore = self.edits.ignore_mask(data.labels)  # the locks now: an edit may have come since tracking
        data.index = index
        use_sem = frame.labels is not None
        timings: dict[str, float] = {}
        with stage("densify"):
            added = self._densify(data, frame, c2w, index)
        timings["densify"] = time.perf_counter() - t0
        mapping, window = None, None
        every = self.config.mapping.every  # live mapping skips frames: the first past each multiple of `every`
        last = self._last_mapped
        if (last is None or index // every > last // every) and self.config.mapping.iterations > 0:
            self._last_mapped = index
            t_sel = time.perf_counter()
            with stage("keyframe_selection"):
                window = self._select_window(data, c2w, frame.labels, index)
            timings["keyframe_selection"] = time.perf_counter() - t_sel
            result = self._map(data, c2w, window, use_sem, between_iterations)
            self._set_gaussians(result.gaussians)
            mapping = result.stats
        if self.config.mapping.refresh_labels and use_sem:
            self._refresh_labels()
        keyframe = is_keyframe(index, self.config.keyframes.every, self.keyframes[-1].index if self.keyframes else None)
        if keyframe:
            stored = Frame(frame.rgb, frame.depth, frame.intrinsics, frame.labels, frame.stamp_ns, None, index)
            self.keyframes.add(CompactFrame.from_frame(stored, np.linalg.inv(c2w)))
        elapsed = time.perf_counter() - t0
        timings["map"] = elapsed
        return MapOutcome(mapping, window, keyframe, added, elapsed, timings)

    # ------------------------------------------------------------------ edits
    def apply_edit(self, request: EditRequest) -> EditRecord:
        """Edit the live map; the edited classes stay locked (ignored in input, frozen) until undone."""
        with self._mutate:
            edited, record = self.edits.apply(self.gaussians, request, self.codec.table)
            self._set_gaussians(edited)
            return record

    def undo_edit(self) -> EditRecord:
        """Revert the last edit, keeping the mapping done since, and unlock its classes."""
        with self._mutate:
            restored, record = self.edits.undo(self.gaussians)
            self._set_gaussians(restored)
            return record

    @property
    def locked_labels(self) -> frozenset[int]:
        """Classes locked by edits."""
        return self.edits.locked_labels

    # ------------------------------------------------------------------ map files
    def load_map(self, saved: MapFile) -> None:
        """Resume in a saved map: the next frame is tracked against it, starting at its last pose."""
        if saved.gaussians.num_semantic != self.codec.num_channels:
            raise FrameError(
                f"the map has {saved.gaussians.num_semantic} semantic channels but semantic.mode={self.codec.mode} "
                f"needs {self.codec.num_channels}"
            )
        with self._mutate:
            self._load(saved)

    def _load(self, saved: MapFile) -> None:
        self.reset()
        self.edits = EditLocks(frozenset(saved.locked_labels))
        self.codec = self.codec.with_table(saved.label_table)
        self._set_gaussians(saved.gaussians.to(self.device))
        with self._lock:
            self.seen_ids = {0, *saved.seen_labels}
        if saved.trajectory:
            self.initial_c2w = saved.trajectory[-1][2].copy()
            self._resumed_poses = [c2w.copy() for _, _, c2w in saved.trajectory[-2:]]
        # frame indices (keyframe ages) go on from the saved run
        self.frames_processed = saved.frames_processed if saved.frames_processed is not None else len(saved.trajectory)
        self.keyframes = KeyframeStore(self.config.keyframes, saved.keyframe_images)
        with_images = {kf.index for kf in saved.keyframe_images}
        self._loaded_keyframe_poses = [(i, p) for i, p in saved.keyframes if i not in with_images]
        self._loaded_trajectory = list(saved.trajectory)
        if saved.scene_radius is not None:
            self.scene_radius = saved.scene_radius
        self.intrinsics = saved.intrinsics

    def to_map_file(self, keyframe_images: int = 16) -> MapFile:
        """Everything needed to resume, for :func:`~sgs_slam_core.mapio.save_map`.

        ``keyframe_images``: how many of the most recent keyframes keep their images (0 = poses only).
        """
        images = self.keyframes[-keyframe_images:] if keyframe_images > 0 else []
        return MapFile(self.gaussians, self.codec.table, config_to_dict(self.config), self.intrinsics,
                       [*self._loaded_keyframe_poses, *self.keyframe_poses()],
                       [*self._loaded_trajectory, *self.trajectory], self.label_candidates(), self.scene_radius,
                       sorted(self.locked_labels), list(images), self.frames_processed)  # fmt: skip

    def set_map(self, gaussians: GaussianMap) -> None:
        """Replace the map (a tracker following a mapper's published map)."""
        if gaussians.num_semantic != self.codec.num_channels:
            raise FrameError(
                f"map has {gaussians.num_semantic} semantic channels, config expects {self.codec.num_channels}"
            )
        with self._mutate:
            self._set_gaussians(gaussians.to(self.device))

    def _set_gaussians(self, gaussians: GaussianMap) -> None:
        if self.device.type == "cuda":
            stream = torch.cuda.current_stream(self.device)
            if stream != torch.cuda.default_stream(self.device):
                stream.synchronize()  # made on a side stream (live mapping): complete before it is shared
        with self._lock:
            self.gaussians = gaussians

    def _validate(self, frame: Frame) -> None:
        if self.intrinsics is None:
            self.intrinsics = frame.intrinsics
        elif frame.intrinsics != self.intrinsics:
            raise FrameError(f"frame intrinsics {frame.intrinsics} differ from the first frame's {self.intrinsics}")
        if frame.valid_depth_fraction == 0:
            raise FrameError("frame has no valid depth: SGS-SLAM needs an RGB-D frame")
        if self.trajectory and frame.stamp_ns < self.trajectory[-1][1]:
            raise FrameError(f"time stamp went backwards: {frame.stamp_ns} < {self.trajectory[-1][1]} ns")

    def _frame_tensors(self, frame: Frame) -> FrameTensors:
        with stage("upload"):
            data = FrameTensors.from_frame(frame, self.codec, self.device)
            data.ignore = self.edits.ignore_mask(data.labels)
        return data

    def _gt_in_map_frame(self, gt_c2w: np.ndarray) -> np.ndarray:
        """Ground truth re-expressed so that the first frame's ground truth maps to ``initial_c2w``."""
        if self._gt_origin is None:
            raise FrameError("use_gt_pose needs ground truth on the first frame too")
        return self.initial_c2w @ np.linalg.inv(self._gt_origin) @ gt_c2w

    def _track(self, data: FrameTensors, frame: Frame, newer_frame_waiting: Callable[[], bool] | None) -> TrackResult:
        poses = [*self._resumed_poses, *(c2w for _, _, c2w in self.trajectory[-2:])]  # a resumed map goes on moving
        prev = poses[-1] if poses else self.initial_c2w
        prev2 = poses[-2] if len(poses) > 1 and self.config.tracking.constant_velocity else None
        init_c2w = predict_constant_velocity(prev, prev2, self._motion_fraction(frame.stamp_ns))
        if self._icp is not None and self._intervals_since_last(frame.stamp_ns) >= self.config.tracking.icp_min_gap:
            init_c2w, _ = self._icp.refine(torch.where(data.valid, data.depth, 0.0), data.intrinsics, init_c2w)
        use_sem = frame.labels is not None and self.config.tracking.weight_semantic > 0
        return self.tracker.track(self.gaussians, data, np.linalg.inv(init_c2w), use_sem, newer_frame_waiting)

    def _intervals_since_last(self, stamp_ns: int) -> float:
        """Camera frame intervals since the last tracked frame: about 1 when none was dropped, 0 unknown.

        The interval is the shortest stamp gap between two tracked frames so far.
        """
        if not self.trajectory or self._min_interval_ns is None:
            return 0.0
        return (stamp_ns - self.trajectory[-1][1]) / self._min_interval_ns

    def _motion_fraction(self, stamp_ns: int) -> float:
        """Time since the last tracked frame over the gap before it, when frames were skipped (live mode).

        1 when frames came evenly (within a camera's stamp jitter) or stamps are unknown, so lockstep
        runs repeat the last motion exactly as the reference does.
        """
        if len(self.trajectory) < 2:
            return 1.0
        (_, t_prev2, _), (_, t_prev, _) = self.trajectory[-2:]
        last_gap, gap = t_prev - t_prev2, stamp_ns - t_prev
        if last_gap <= 0 or gap <= 0:
            return 1.0
        fraction = gap / last_gap
        return 1.0 if 2 / 3 < fraction < 1.5 else min(fraction, 4.0)

    def _densify(self, data: FrameTensors, frame: Frame, c2w: np.ndarray, index: int) -> int:
        c2w_t = torch.as_tensor(c2w, dtype=torch.float32, device=self.device)
        if len(self.gaussians) == 0:
            mask = data.valid
        else:
            with torch.no_grad():
                out = self.kernels.render(self.gaussians, data.intrinsics, se3_inverse(c2w_t), with_semantics=False)
            mask = densify_mask(out, data, self.config.densify)
        scale = self.config.densify.resolution_scale
        source = data
        if scale < 1.0:
            rgb, depth, labels, k = resize_arrays(frame.rgb, frame.depth, frame.labels, frame.intrinsics, scale)
            source = FrameTensors.from_arrays(index, k, rgb, depth, labels, self.codec, self.device)
            source.ignore = self.edits.ignore_mask(source.labels)
            mask = torch.nn.functional.interpolate(mask[None, None].float(), size=k.shape, mode="nearest")[0, 0] > 0.5
            mask &= source.valid
        new = gaussians_from_pixels(source, c2w_t, mask, self.codec.num_channels, self.config.densify,
                                    generator=self.torch_rng, existing=self.gaussians)  # fmt: skip
        kept, cap = self.gaussians, self.config.densify.max_gaussians
        if cap is not None:  # the Gaussian budget: the least opaque make room
            kept = kept.prune(over_budget(kept, len(new), cap, self.locked_labels))
        self._set_gaussians(kept.cat(new))
        return len(new)

    def _select_window(self, data: FrameTensors, c2w: np.ndarray, labels: np.ndarray | None, index: int) -> Window:
        valid = torch.nonzero(data.valid.reshape(-1)).squeeze(1).cpu().numpy()
        picks = self.rng.choice(valid, size=min(self.config.keyframes.overlap_samples, valid.size), replace=False)
        k = data.intrinsics
        v, u = np.divmod(picks, k.width)
        z = data.depth.reshape(-1)[torch.as_tensor(picks, device=self.device)].cpu().numpy().astype(np.float64)
        cam = np.stack([(u - k.cx) / k.fx * z, (v - k.cy) / k.fy * z, z], axis=1)
        world = cam @ c2w[:3, :3].T + c2w[:3, 3]
        return select_window(self.keyframes, world, labels, index, self.config.keyframes, self.rng)

    def _map(
        self,
        data: FrameTensors,
        c2w: np.ndarray,
        window: Window,
        use_sem: bool,
        between_iterations: Callable[[], bool] | None = None,
    ) -> MapResult:
        frames = []
        for store_index, weight in zip(window.keyframes, window.weights[:-1], strict=True):
            kf = self.keyframes[store_index]
            w2c = torch.as_tensor(kf.w2c, dtype=torch.float32, device=self.device)
            with stage("upload"):
                kf_data = kf.to_tensors(self.codec, self.device)
                kf_data.ignore = self.edits.ignore_mask(kf_data.labels)
            frames.append(WindowFrame(kf_data, w2c, weight))
        w2c_now = torch.as_tensor(np.linalg.inv(c2w), dtype=torch.float32, device=self.device)
        frames.append(WindowFrame(data, w2c_now, window.weights[-1]))
        return map_window(self.gaussians, frames, self.config.mapping, self.kernels, self.scene_radius, use_sem,
                          self.rng, self.locked_labels, between_iterations)  # fmt: skip

    def _refresh_labels(self) -> None:
        current = self.gaussians
        if len(current):
            decoded = self.codec.decode(current.semantics, self.label_candidates()).to(self.device)
            locked = self.locked_labels
            if locked:  # no Gaussian enters or leaves a locked class
                ids = torch.tensor(sorted(locked), dtype=torch.int64, device=self.device)
                keep = torch.isin(current.labels, ids) | torch.isin(decoded, ids)
                decoded = torch.where(keep, current.labels, decoded)
            self._set_gaussians(current.with_tensors(labels=decoded))

    # ------------------------------------------------------------------ queries
    def label_candidates(self) -> list[int]:
        """Class ids a decoded label may take: every id seen in the input so far."""
        with self._lock:
            return sorted(self.seen_ids)

    def decode(self, semantic: torch.Tensor) -> torch.Tensor:  # [..., S] -> [...]
        """Class ids from semantic features (rendered or per Gaussian)."""
        return self.codec.decode(semantic, self.label_candidates())

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
