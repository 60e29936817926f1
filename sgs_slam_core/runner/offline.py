"""``run_offline``: the whole pipeline over a dataset, deterministic for a given config on CPU.

The run folder receives ``trajectory.txt`` (TUM format, camera-to-world), ``metrics.json``,
``groundtruth.txt`` (the dataset's ground truth at the same stamps, TUM format), ``config.yaml``
(resolved), ``run.yaml`` (input and options, for ``sgs-slam eval``, provenance: git commit,
versions, device, and how the run ended), ``frames.csv`` (per-frame timings and counters),
``map.sgsmap`` (native map), ``map.ply`` (3DGS splats), ``renders/`` and ``trajectory.png``.
"""

from __future__ import annotations

import contextlib
import logging
import resource
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from sgs_slam_core.config import dump_yaml
from sgs_slam_core.config.schema import SlamConfig
from sgs_slam_core.datasets.base import Dataset
from sgs_slam_core.errors import DatasetError, EvaluationError, FrameError, OutputError, SgsSlamError
from sgs_slam_core.frame import Frame
from sgs_slam_core.kernels import resolve_backend
from sgs_slam_core.mapio import save_map, write_splat_ply
from sgs_slam_core.metrics import write_tum_trajectory
from sgs_slam_core.profiling import stage
from sgs_slam_core.runner.evaluation import EvalOptions, evaluate
from sgs_slam_core.runner.outputs import RESULT_FILES, prepare_run_dir, remove_run, write_csv
from sgs_slam_core.runner.progress import SlamProgress
from sgs_slam_core.runner.realtime import RealtimeOptions, RealtimeStats, run_realtime
from sgs_slam_core.runner.report import write_metrics
from sgs_slam_core.runner.run_info import write_run_info
from sgs_slam_core.runner.run_record import GROUND_TRUTH_FILE, environment, write_ground_truth
from sgs_slam_core.runner.safety import RunInterrupted, StopRequest
from sgs_slam_core.slam.footprint import footprint
from sgs_slam_core.slam.system import Slam, StepResult
from sgs_slam_core.viz.viewer import Viewer

__all__ = ["RunResult", "run_offline"]

log = logging.getLogger(__name__)

_STOP_MESSAGE = "interrupted: finishing this frame, then writing the run folder (Ctrl-C again to abort)"

_CSV_FIELDS = ("frame", "dataset_index", "stamp_ns", "track_ms", "map_ms", "track_iterations", "track_converged",
               "track_residual_cm", "map_iterations", "added", "pruned", "gaussians", "keyframe", "window",
               "tracking_failed", "tracking_state", "reason")  # fmt: skip


@dataclass
class RunResult:
    """A finished run."""

    out_dir: Path
    metrics: dict[str, Any]
    slam: Slam
    frame_indices: list[int] = field(default_factory=list)
    steps: list[StepResult] = field(default_factory=list)


def _announce(line: str) -> None:
    """A line for the user before the progress bar runs (compiling, decoding ahead), on stderr."""
    print(line, file=sys.stderr)


def _peak_memory_mb(device: torch.device) -> float:
    if device.type == "cuda":
        return torch.cuda.max_memory_allocated(device) / 2**20
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _csv_row(step: StepResult, dataset_index: int) -> dict[str, Any]:
    tr, mp = step.track.result, step.map.stats
    return {
        "frame": step.index,
        "dataset_index": dataset_index,
        "stamp_ns": step.track.stamp_ns,
        "track_ms": round(step.track.time_s * 1e3, 2),
        "map_ms": round(step.map.time_s * 1e3, 2),
        "track_iterations": tr.iterations if tr else 0,
        "track_converged": int(bool(tr and tr.converged)),
        "track_residual_cm": round(tr.depth_residual_m * 100, 4) if tr else "",
        "map_iterations": mp.iterations if mp else 0,
        "added": step.map.added,
        "pruned": mp.pruned if mp else 0,
        "gaussians": step.num_gaussians,
        "keyframe": int(step.map.keyframe),
        "window": len(step.map.window.keyframes) + 1 if step.map.window else 0,
        "tracking_failed": int(step.track.failed),
        "tracking_state": step.track.state,
        "reason": step.track.failure_reason or "",
    }


@dataclass
class _Loop:
    """What the frame loop produced."""

    frame_indices: list[int] = field(default_factory=list)  # dataset indices of processed frames
    poses: list[np.ndarray] = field(default_factory=list)
    gts: list[np.ndarray | None] = field(default_factory=list)  # ground-truth c2w (dataset frame) or None
    steps: list[StepResult] = field(default_factory=list)
    rows: list[dict[str, Any]] = field(default_factory=list)
    track_s: float = 0.0
    map_s: float = 0.0
    load_s: float = 0.0
    bad_frames: int = 0
    first_skip: str = ""  # why the first skipped frame was skipped
    interrupted: bool = False  # stopped by Ctrl-C before the last frame
    live: RealtimeStats | None = None  # realtime runs: what a live camera would have seen

    def add(self, index: int, step: StepResult, gt_c2w: np.ndarray | None) -> None:
        """Record a processed frame (``index``: its position in the dataset)."""
        self.frame_indices.append(index)
        self.poses.append(step.c2w)
        self.gts.append(gt_c2w)
        self.steps.append(step)
        self.rows.append(_csv_row(step, index))
        self.track_s += step.track.time_s
        self.map_s += step.map.time_s


def _process_all(slam: Slam, dataset: Dataset, observers: list[Viewer], should_stop: Callable[[], bool]) -> _Loop:
    """Feed every frame to ``slam``; frames it rejects or that cannot be read are counted and skipped."""
    loop = _Loop()
    for i in range(len(dataset)):
        if should_stop():
            loop.interrupted = True
            break
        t0 = time.perf_counter()
        try:
            with stage("data_loading"):
                frame = dataset[i]
            loop.load_s += time.perf_counter() - t0
            step = slam.process(frame)
        except (FrameError, DatasetError) as err:
            loop.bad_frames += 1
            loop.first_skip = loop.first_skip or f"frame {i}: {err}"
            log.warning("frame %d skipped: %s", i, err)
            continue
        loop.add(i, step, frame.gt_c2w)
        for observer in observers:  # progress bar, live viewer
            observer.log_step(frame, step, slam)
    return loop


def _process_realtime(
    slam: Slam, dataset: Dataset, options: RealtimeOptions, observers: list[Viewer], should_stop: Callable[[], bool]
) -> _Loop:
    """Release the frames on time into the live pipeline; tracked frames only, in order."""

    def on_tracked(frame: Frame, step: StepResult) -> None:
        for observer in observers:  # progress bar (frames not tracked count as passed), live viewer
            observer.log_step(frame, step, slam)

    live = run_realtime(slam, dataset, options, on_tracked, should_stop, _announce)
    loop = _Loop(
        bad_frames=live.stats.bad_frames, first_skip=live.first_skip, interrupted=live.interrupted, live=live.stats
    )
    for index, step, gt in zip(live.dataset_indices, live.steps, live.gt_c2w, strict=True):
        loop.add(index, step, gt)
    return loop


def _write_outputs(out: Path, slam: Slam, loop: _Loop) -> None:
    """trajectory.txt, groundtruth.txt, frames.csv, map.sgsmap and map.ply, smallest first, each atomically."""
    stamps = [s.stamp_ns for s in loop.steps]
    write_tum_trajectory(out / "trajectory.txt", stamps, np.stack(loop.poses))
    write_ground_truth(out / GROUND_TRUTH_FILE, stamps, loop.gts)
    write_csv(out / "frames.csv", _CSV_FIELDS, loop.rows)
    map_file = slam.to_map_file()
    map_file.trajectory = list(zip(loop.frame_indices, stamps, loop.poses, strict=True))  # dataset frame indices
    save_map(out / "map.sgsmap", map_file)
    write_splat_ply(out / "map.ply", slam.gaussians, slam.codec.table)


def _timing(loop: _Loop) -> dict[str, Any]:
    """Speed and frame counts: lockstep processes every frame; realtime reports what it kept up with."""
    frames, live = len(loop.frame_indices), loop.live
    mapped = [s for s in loop.steps if s.map.stats is not None]
    map_steps = sum(s.map.stats.iterations for s in mapped if s.map.stats is not None) / max(len(mapped), 1)
    if live is None:
        return {
            "fps": frames / max(loop.track_s + loop.map_s, 1e-9),
            "track_ms_per_frame": 1e3 * loop.track_s / frames,
            "map_ms_per_frame": 1e3 * loop.map_s / frames,
            "load_ms_per_frame": 1e3 * loop.load_s / frames,
            "frames_in": frames + loop.bad_frames,
            "frames_tracked": frames,
            "frames_dropped": 0,
            "frames_mapped": len(mapped),
            "map_steps_per_frame": map_steps,
            "realtime_hz": None,
        }
    return {
        "fps": frames / max(live.wall_s, 1e-9),
        "track_ms_per_frame": 1e3 * loop.track_s / frames,
        "map_ms_per_frame": 1e3 * sum(s.map.time_s for s in mapped) / max(len(mapped), 1),
        "frames_in": live.frames_in,
        "frames_tracked": live.frames_tracked,
        "frames_dropped": live.frames_dropped,
        "frames_mapped": live.frames_mapped,
        "map_steps_per_frame": map_steps,
        "realtime_hz": live.realtime_hz,
        "late_frames": live.late_frames,
        "preloaded_frames": live.preloaded_frames,
        "wall_s": live.wall_s,
        "labels_in": live.labels_in,
        "labels_fused": live.labels_fused,
        "labels_unmatched": live.labels_unmatched,
        "label_latency_ms": live.label_latency_ms,
    }


def _stats(slam: Slam, loop: _Loop, config: SlamConfig) -> dict[str, Any]:
    """The metrics that come from the run itself (speed, memory, counters), not from the evaluation."""
    return {
        "frames": len(loop.frame_indices),
        **_timing(loop),
        **footprint(slam).as_metrics(),  # Gaussians and keyframes held, and their bytes
        "peak_memory_mb": _peak_memory_mb(slam.device),
        "tracking_failures": slam.failures,
        **_lost_and_found(slam),
        "bad_frames": loop.bad_frames,
        "device": str(slam.device),
        "render_backend": resolve_backend(config.render.backend, slam.device),
    }


def _lost_and_found(slam: Slam) -> dict[str, int]:
    """How often the camera was lost and relocalized, and the frames that came while it was lost."""
    counts = slam.guard.counts()
    return {
        "tracking_lost_events": counts.lost_events,
        "relocalizations": counts.relocalizations,
        "frames_while_lost": counts.frames_while_lost,
    }


def _track_and_map(
    dataset: Dataset,
    config: SlamConfig,
    out: Path,
    overwrite: bool,
    provenance: dict[str, Any],
    show_progress: bool,
    realtime: RealtimeOptions | None,
    viewer: Viewer | None,
) -> tuple[Slam, _Loop]:
    """Create the run folder, process the frames, write the results (see :func:`run_offline` on failures)."""
    created = prepare_run_dir(out, overwrite)
    if realtime is not None:
        config = config.for_live()
    try:
        dump_yaml(config, out / "config.yaml")
        torch.manual_seed(config.seed)
        slam = Slam(config, dataset.label_table)
        provenance.update(environment(slam.device))
        write_run_info(out / "run.yaml", provenance, "running")
        sample = dataset[0] if config.render.compile and len(dataset) else None  # render.compile traces on it
        slam.prepare(_announce, sample)  # compile before anything is timed
        label = "slam" if realtime is None else "slam (realtime)"
        observers: list[Viewer] = [
            *([SlamProgress(len(dataset), label)] if show_progress else []),
            *([viewer] if viewer else []),
        ]
        try:
            with StopRequest(_STOP_MESSAGE) as stop:
                if realtime is None:
                    loop = _process_all(slam, dataset, observers, stop)
                else:
                    loop = _process_realtime(slam, dataset, realtime, observers, stop)
        finally:
            for observer in observers:  # idempotent: flushes a viewer's stream when the loop stopped early
                observer.close()
        if not loop.frame_indices:
            if loop.interrupted:
                raise KeyboardInterrupt  # interrupted before the first frame: nothing worth keeping
            raise DatasetError(
                f"no frame could be processed: {loop.bad_frames} skipped, the first one: "
                f"{loop.first_skip or 'none was tracked'}"
            )
        _write_outputs(out, slam, loop)
    except OutputError as err:  # e.g. a full disk: keep the results written before it, and say which
        kept = [name for name in RESULT_FILES if (out / name).is_file()]
        if not kept:
            remove_run(out, created)
            raise
        note = f"{err}; written before it: {', '.join(kept)}"
        with contextlib.suppress(OutputError):
            write_run_info(out / "run.yaml", provenance, "failed", note)
        raise OutputError(f"{note} (in {out})") from err
    except BaseException:
        remove_run(out, created)  # aborted before its results were complete: leave nothing behind
        raise
    return slam, loop


def _evaluate(
    dataset: Dataset, truth: Dataset | None, slam: Slam, loop: _Loop, config: SlamConfig, options: EvalOptions
) -> dict[str, Any]:
    """The run's metrics: trajectory against ground truth, and the map's renders against the input (or ``truth``)."""
    candidates = slam.label_candidates()
    return evaluate(
        truth or dataset,
        loop.frame_indices,
        loop.poses,
        slam.gaussians,
        slam.codec,
        candidates,
        config.render,
        options,
        fed=dataset if truth is not None else None,
    )


def run_offline(
    dataset: Dataset,
    config: SlamConfig,
    out: str | Path,
    overwrite: bool = False,
    provenance: dict[str, Any] | None = None,
    show_progress: bool = True,
    render_examples: int = 4,
    realtime: RealtimeOptions | None = None,
    viewer: Viewer | None = None,
    truth: Dataset | None = None,
) -> RunResult:
    """Process every frame, save the outputs, evaluate, and return the metrics.

    ``realtime``: release the frames at their stamps (or a rate) into the live pipeline instead of
    processing every frame in lockstep; metrics and ATE then cover the frames it kept up with.
    ``viewer`` (see :func:`sgs_slam_core.viz.open_viewer`) receives every processed frame live.
    ``truth``: the frames the map is scored against when ``dataset`` feeds other labels
    (:class:`~sgs_slam_core.datasets.label_noise.NoisyLabels`); default ``dataset``.

    The results (trajectory, frames.csv, maps) are written before the evaluation, so a failing
    evaluation (raised as :class:`EvaluationError`) never loses them. The first Ctrl-C stops after
    the current frame and writes the folder for the frames processed so far (raised as
    :class:`RunInterrupted` once written, without evaluation); a second Ctrl-C, or one before any
    frame was processed, leaves no run folder. A result that cannot be written (disk full) raises
    :class:`OutputError` naming it and the results written before it. ``run.yaml`` says how the
    run ended.
    """
    out, provenance = Path(out), dict(provenance or {})
    slam, loop = _track_and_map(dataset, config, out, overwrite, provenance, show_progress, realtime, viewer)
    stats = _stats(slam, loop, config)
    done = {"frames_processed": len(loop.frame_indices), "frames_in_input": len(dataset)}
    if loop.interrupted:
        note = (
            f"interrupted by Ctrl-C after {len(loop.frame_indices)} of {len(dataset)} frames; the results "
            f"hold those frames, not evaluated (run: sgs-slam eval {out})"
        )
        write_metrics(out / "metrics.json", {**stats, "interrupted": True})
        write_run_info(out / "run.yaml", provenance, "interrupted", note, **done)
        raise RunInterrupted(f"{note}; run folder: {out}")
    try:
        options = EvalOptions(config.eval_every, render_examples, out)
        metrics = _evaluate(dataset, truth, slam, loop, config, options)
    except KeyboardInterrupt:
        note = f"evaluation interrupted by Ctrl-C; the results are complete (run: sgs-slam eval {out})"
        write_metrics(out / "metrics.json", {**stats, "evaluation": "interrupted"})
        write_run_info(out / "run.yaml", provenance, "evaluation_failed", note, **done)
        raise RunInterrupted(f"{note}; run folder: {out}") from None
    except Exception as err:  # a bug or running out of memory in the evaluation must not cost the run
        reason = str(err) if isinstance(err, SgsSlamError) else f"{type(err).__name__}: {err}"
        note = f"the run is complete but its evaluation failed: {reason}"
        write_metrics(out / "metrics.json", {**stats, "evaluation_error": reason})
        write_run_info(out / "run.yaml", provenance, "evaluation_failed", note, **done)
        kept = f"trajectory.txt and map.sgsmap are in {out} (retry: sgs-slam eval {out})"
        raise EvaluationError(f"{note}; {kept}") from err
    metrics.update(stats)
    write_metrics(out / "metrics.json", metrics)
    write_run_info(out / "run.yaml", provenance, "complete", **done)
    return RunResult(out, metrics, slam, loop.frame_indices, loop.steps)
