"""``run_offline``: the whole pipeline over a dataset, deterministic for a given config on CPU.

The run folder receives ``trajectory.txt`` (TUM format, camera-to-world), ``metrics.json``,
``groundtruth.txt`` (the dataset's ground truth at the same stamps, TUM format), ``config.yaml``
(resolved), ``run.yaml`` (input and options, for ``sgs-slam eval``, and provenance: git commit,
versions, device), ``frames.csv`` (per-frame timings and counters), ``map.sgsmap`` (native map),
``map.ply`` (3DGS splats), ``renders/`` and ``trajectory.png``.
"""

from __future__ import annotations

import csv
import logging
import resource
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.profiler import record_function

from sgs_slam_core.config import dump_yaml
from sgs_slam_core.config.schema import SlamConfig
from sgs_slam_core.datasets.base import Dataset
from sgs_slam_core.errors import DatasetError, FrameError
from sgs_slam_core.frame import Frame
from sgs_slam_core.mapio import save_map, write_splat_ply
from sgs_slam_core.metrics import write_tum_trajectory
from sgs_slam_core.render.api import resolve_backend
from sgs_slam_core.runner.evaluation import EvalOptions, evaluate
from sgs_slam_core.runner.progress import SlamProgress
from sgs_slam_core.runner.realtime import RealtimeOptions, RealtimeStats, run_realtime
from sgs_slam_core.runner.report import write_metrics
from sgs_slam_core.runner.run_record import GROUND_TRUTH_FILE, write_ground_truth, write_run_yaml
from sgs_slam_core.slam.system import Slam, StepResult
from sgs_slam_core.viz.viewer import Viewer

__all__ = ["RunResult", "check_run_dir", "prepare_run_dir", "run_offline"]

log = logging.getLogger(__name__)

_CSV_FIELDS = ("frame", "dataset_index", "stamp_ns", "track_ms", "map_ms", "track_iterations", "track_converged",
               "track_residual_cm", "map_iterations", "added", "pruned", "gaussians", "keyframe", "window",
               "tracking_failed", "reason")  # fmt: skip


@dataclass
class RunResult:
    """A finished run."""

    out_dir: Path
    metrics: dict[str, Any]
    slam: Slam
    frame_indices: list[int] = field(default_factory=list)
    steps: list[StepResult] = field(default_factory=list)


def check_run_dir(out: Path, overwrite: bool) -> None:
    """Raise unless ``out`` is absent, empty, or may be replaced (call before any long work)."""
    if out.exists() and (not out.is_dir() or any(out.iterdir())) and not overwrite:
        raise DatasetError(f"output folder {out} exists and is not empty (use --overwrite to replace it)")


def prepare_run_dir(out: Path, overwrite: bool) -> None:
    """Create ``out``; an existing non-empty folder is refused unless ``overwrite`` (then replaced)."""
    check_run_dir(out, overwrite)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        shutil.rmtree(out) if out.is_dir() else out.unlink()
    out.mkdir(parents=True, exist_ok=True)


def _peak_memory_mb(device: torch.device) -> float:
    if device.type == "cuda":
        return torch.cuda.max_memory_allocated(device) / 2**20
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _csv_row(step: StepResult, dataset_index: int) -> dict[str, Any]:
    tr, mp = step.tracking, step.mapping
    return {
        "frame": step.index, "dataset_index": dataset_index, "stamp_ns": step.stamp_ns,
        "track_ms": round(step.track_time_s * 1e3, 2), "map_ms": round(step.map_time_s * 1e3, 2),
        "track_iterations": tr.iterations if tr else 0, "track_converged": int(bool(tr and tr.converged)),
        "track_residual_cm": round(tr.depth_residual_m * 100, 4) if tr else "",
        "map_iterations": mp.iterations if mp else 0, "added": step.added, "pruned": mp.pruned if mp else 0,
        "gaussians": step.num_gaussians, "keyframe": int(step.keyframe),
        "window": len(step.window.keyframes) + 1 if step.window else 0,
        "tracking_failed": int(step.tracking_failed), "reason": step.failure_reason or "",
    }  # fmt: skip


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


def _process_all(slam: Slam, dataset: Dataset, show_progress: bool, viewer: Viewer | None = None) -> _Loop:
    """Feed every frame to ``slam``; frames it rejects are counted and skipped."""
    loop = _Loop()
    observers = [*([SlamProgress(len(dataset))] if show_progress else []), *([viewer] if viewer else [])]
    for i in range(len(dataset)):
        t0 = time.perf_counter()
        with record_function("data_loading"):
            frame = dataset[i]
        loop.load_s += time.perf_counter() - t0
        try:
            step = slam.process(frame)
        except FrameError as err:
            loop.bad_frames += 1
            log.warning("frame %d skipped: %s", i, err)
            continue
        loop.frame_indices.append(i)
        loop.poses.append(step.c2w)
        loop.gts.append(frame.gt_c2w)
        loop.steps.append(step)
        loop.rows.append(_csv_row(step, i))
        loop.track_s += step.track_time_s
        loop.map_s += step.map_time_s
        for observer in observers:  # progress bar, live viewer
            observer.log_step(frame, step, slam)
    for observer in observers:
        observer.close()
    if not loop.frame_indices:
        raise DatasetError("no frame could be processed")
    return loop


def _process_realtime(
    slam: Slam, dataset: Dataset, hz: float | None, show_progress: bool, viewer: Viewer | None = None
) -> tuple[_Loop, RealtimeStats]:
    """Release the frames on time into the live pipeline; tracked frames only, in order."""
    observers = [*([SlamProgress(len(dataset), "slam (realtime)")] if show_progress else []),
                 *([viewer] if viewer else [])]  # fmt: skip

    def on_tracked(frame: Frame, step: StepResult) -> None:
        for observer in observers:  # progress bar (frames not tracked count as passed), live viewer
            observer.log_step(frame, step, slam)

    live = run_realtime(slam, dataset, hz, on_tracked)
    for observer in observers:
        observer.close()
    if not live.steps:
        raise DatasetError("no frame could be processed")
    loop = _Loop(bad_frames=live.stats.bad_frames if live.stats else 0)
    for index, step, gt in zip(live.dataset_indices, live.steps, live.gt_c2w, strict=True):
        loop.frame_indices.append(index)
        loop.poses.append(step.c2w)
        loop.gts.append(gt)
        loop.steps.append(step)
        loop.rows.append(_csv_row(step, index))
        loop.track_s += step.track_time_s
        loop.map_s += step.map_time_s
    assert live.stats is not None
    return loop, live.stats


def _timing_metrics(loop: _Loop, live: RealtimeStats | None) -> dict[str, Any]:
    """Speed and frame counts: lockstep processes every frame; realtime reports what it kept up with."""
    frames = len(loop.frame_indices)
    if live is None:
        return {"fps": frames / max(loop.track_s + loop.map_s, 1e-9), "track_ms_per_frame": 1e3 * loop.track_s / frames,
                "map_ms_per_frame": 1e3 * loop.map_s / frames, "load_ms_per_frame": 1e3 * loop.load_s / frames,
                "frames_in": frames + loop.bad_frames, "frames_tracked": frames, "frames_dropped": 0,
                "frames_mapped": sum(s.mapping is not None for s in loop.steps), "realtime_hz": None}  # fmt: skip
    mapped = [s for s in loop.steps if s.mapping is not None]
    return {"fps": frames / max(live.wall_s, 1e-9), "track_ms_per_frame": 1e3 * loop.track_s / frames,
            "map_ms_per_frame": 1e3 * sum(s.map_time_s for s in mapped) / max(len(mapped), 1),
            "frames_in": live.frames_in, "frames_tracked": live.frames_tracked, "frames_dropped": live.frames_dropped,
            "frames_mapped": live.frames_mapped, "realtime_hz": live.realtime_hz, "late_frames": live.late_frames,
            "wall_s": live.wall_s}  # fmt: skip


def _write_outputs(out: Path, slam: Slam, loop: _Loop) -> None:
    """trajectory.txt, frames.csv, map.sgsmap and map.ply."""
    stamps = [s.stamp_ns for s in loop.steps]
    write_tum_trajectory(out / "trajectory.txt", stamps, np.stack(loop.poses))
    write_ground_truth(out / GROUND_TRUTH_FILE, stamps, loop.gts)
    with (out / "frames.csv").open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=_CSV_FIELDS)
        writer.writeheader()
        writer.writerows(loop.rows)
    map_file = slam.to_map_file()
    map_file.trajectory = list(zip(loop.frame_indices, stamps, loop.poses, strict=True))  # dataset frame indices
    save_map(out / "map.sgsmap", map_file)
    write_splat_ply(out / "map.ply", slam.gaussians, slam.codec.table)


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
) -> RunResult:
    """Process every frame, save the outputs, evaluate, and return the metrics.

    ``realtime``: release the frames at their stamps (or a rate) into the live pipeline instead of
    processing every frame in lockstep; metrics and ATE then cover the frames it kept up with.
    ``viewer`` (see :func:`sgs_slam_core.viz.open_viewer`) receives every processed frame live.
    """
    out = Path(out)
    prepare_run_dir(out, overwrite)
    dump_yaml(config, out / "config.yaml")
    torch.manual_seed(config.seed)
    slam = Slam(config, dataset.label_table)
    write_run_yaml(out / "run.yaml", provenance, slam.device)
    slam.prepare(lambda line: print(line, file=sys.stderr))  # compile before anything is timed
    live = None
    try:
        if realtime is None:
            loop = _process_all(slam, dataset, show_progress, viewer)
        else:
            loop, live = _process_realtime(slam, dataset, realtime.hz, show_progress, viewer)
    finally:
        if viewer is not None:  # idempotent: flushes the stream when the loop stopped early
            viewer.close()
    _write_outputs(out, slam, loop)
    metrics: dict[str, Any] = evaluate(
        dataset, loop.frame_indices, loop.poses, slam.gaussians, slam.codec, slam.label_candidates(), config.render,
        EvalOptions(config.eval_every, render_examples, out),
    )  # fmt: skip
    metrics.update(_timing_metrics(loop, live))
    metrics.update(
        num_gaussians=slam.num_gaussians,
        peak_memory_mb=_peak_memory_mb(slam.device),
        tracking_failures=slam.failures,
        bad_frames=loop.bad_frames,
        keyframes=len(slam.keyframes),
        device=str(slam.device),
        render_backend=resolve_backend(config.render.backend, slam.device),
    )
    write_metrics(out / "metrics.json", metrics)
    return RunResult(out, metrics, slam, loop.frame_indices, loop.steps)
