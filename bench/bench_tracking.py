"""Tracking benchmark: every tracker on the same frames against the same map, then each in its own run.

Pass 1 runs the SLAM in lockstep with the driving tracker (``--driver``, default the preset's) and,
at every tracked frame, runs each tracker from the same predicted pose on the same map, in
alternating order: time per frame, iterations and renders per frame, and the pose error against
the ground truth (in the map frame). Pass 2 runs the whole SLAM once per tracker (and seed) for
its ATE. Appends the tables to BENCHMARKS.md.

    python bench/bench_tracking.py [INPUT] [--downscale F] [--preset P] [--max-frames N]
                                   [--trackers adam gauss_newton] [--seeds 0 1] [--set KEY=VALUE]
                                   [--skip-runs] [--no-append]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import append_section, markdown_table
from sgs_slam_core.cli.demo import default_room_dir, ensure_room
from sgs_slam_core.cli.run import default_preset
from sgs_slam_core.config import SlamConfig, load_config
from sgs_slam_core.datasets import DatasetOptions, open_dataset
from sgs_slam_core.datasets.base import Dataset
from sgs_slam_core.frame_data import FrameTensors
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.kernels import build_kernels
from sgs_slam_core.runner import run_offline
from sgs_slam_core.slam.features import Landmarks
from sgs_slam_core.slam.system import Slam, resolve_device
from sgs_slam_core.slam.tracker import TrackResult
from sgs_slam_core.slam.trackers import Tracker, build_tracker


@dataclass
class TrackerLog:
    """Per-frame records of one tracker in pass 1."""

    ms: list[float] = field(default_factory=list)
    iterations: list[int] = field(default_factory=list)
    renders: list[int] = field(default_factory=list)
    w2c: list[np.ndarray] = field(default_factory=list)


class SideBySide:
    """A tracker that runs every tracker on each call (alternating order) and returns the driver's result."""

    def __init__(self, trackers: dict[str, Tracker], driver: str) -> None:
        self.trackers, self.driver = trackers, driver
        self.logs = {name: TrackerLog() for name in trackers}
        self.calls = 0

    def track(
        self,
        gaussians: GaussianMap,
        frame: FrameTensors,
        init_w2c: np.ndarray,
        use_semantics: bool,
        newer_frame_waiting: Callable[[], bool] | None = None,
        landmarks: Landmarks | None = None,
    ) -> TrackResult:
        """Every tracker from ``init_w2c`` with the frame's feature landmarks; the driver's result."""
        names = list(self.trackers)
        order = names if self.calls % 2 == 0 else names[::-1]
        self.calls += 1
        results = {}
        for name in order:
            t0 = time.perf_counter()
            tracker = self.trackers[name]
            results[name] = result = tracker.track(gaussians, frame, init_w2c, use_semantics, None, landmarks)
            log = self.logs[name]
            log.ms.append((time.perf_counter() - t0) * 1e3)
            log.iterations.append(result.iterations)
            log.renders.append(result.renders)
            log.w2c.append(result.w2c)
        return results[self.driver]


@dataclass(frozen=True)
class Truth:
    """What a tracked frame's relative motion is judged by: the last pose and both ground truths."""

    previous_c2w: np.ndarray  # [4, 4] the driver's pose of the previous tracked frame (map frame)
    previous_gt: np.ndarray  # [4, 4] its ground truth (dataset frame)
    gt: np.ndarray  # [4, 4] this frame's ground truth


def tracker_config(spec: str, preset: str, overrides: list[str]) -> SlamConfig:
    """``METHOD[:KEY=VALUE;...]`` (keys under ``tracking.``) applied over the run's configuration."""
    method, _, extra = spec.partition(":")
    more = [f"tracking.{kv}" for kv in extra.split(";") if kv]
    return load_config(preset, None, [*overrides, f"tracking.method={method}", *more])


def same_map_pass(
    dataset: Dataset, config: SlamConfig, trackers: dict[str, Tracker], driver: str
) -> tuple[SideBySide, list]:
    """Pass 1: the logs and, per tracked frame, its :class:`Truth` (None without ground truth)."""
    slam = Slam(config, dataset.label_table)
    slam.prepare(lambda line: print(line, flush=True), dataset[0] if len(dataset) else None)  # compiled, not timed
    side = SideBySide(trackers, driver)
    slam.tracker = slam.localizer.tracker = side  # the localizer runs the tracker it was built with
    truth: list[Truth | None] = []
    previous = None
    for i in range(len(dataset)):
        frame = dataset[i]
        before = side.calls
        step = slam.process(frame)
        if side.calls > before:
            usable = previous is not None and previous[1] is not None and frame.gt_c2w is not None
            truth.append(Truth(previous[0], previous[1], frame.gt_c2w) if usable else None)
        previous = (step.c2w, frame.gt_c2w)
    return side, truth


def _error_mm(w2c: list[np.ndarray], truth: list[Truth | None]) -> float:
    """Median error of the frame-to-frame translation against the ground truth's (mm)."""
    errors = []
    for pose, t in zip(w2c, truth, strict=True):
        if t is not None:
            moved = np.linalg.inv(t.previous_c2w) @ np.linalg.inv(pose)
            true = np.linalg.inv(t.previous_gt) @ t.gt
            errors.append(np.linalg.norm(moved[:3, 3] - true[:3, 3]))
    return float(np.median(errors)) * 1e3 if errors else float("nan")


def same_map_table(side: SideBySide, truth: list, baseline: str) -> str:
    """Markdown rows: per tracker time, ratio to the baseline, iterations, renders, median error."""
    base = np.median(side.logs[baseline].ms)
    rows = []
    for name, log in side.logs.items():
        med = float(np.median(log.ms))
        rows.append(
            [
                name,
                f"{med:.1f}",
                f"{np.percentile(log.ms, 95):.1f}",
                f"{med / base:.2f}",
                f"{np.mean(log.iterations):.1f}",
                f"{np.mean(log.renders):.1f}",
                f"{_error_mm(log.w2c, truth):.2f}",
            ]
        )
    headers = [
        "tracker",
        "ms/frame (median)",
        "p95",
        f"ratio to {baseline}",
        "iterations/frame",
        "renders/frame",
        "motion error vs ground truth (median mm/frame)",
    ]
    return markdown_table(headers, rows)


def own_runs_table(dataset: Dataset, configs: dict[str, SlamConfig], seeds: list[int]) -> str:
    """Pass 2: each tracker drives its own lockstep run per seed; ATE, tracking ms/frame, mIoU."""
    rows = []
    for name, config in configs.items():
        ates, track_ms, mious = [], [], []
        for seed in seeds:
            out = Path(tempfile.mkdtemp(prefix="bench_tracking_"))
            cfg = dataclasses.replace(config, seed=seed)
            m = run_offline(dataset, cfg, out, overwrite=True, provenance={"bench": True}, show_progress=False).metrics
            ates.append(float("nan") if m["ate_rmse_m"] is None else m["ate_rmse_m"] * 100)  # None: too few poses
            track_ms.append(m["track_ms_per_frame"])
            if m.get("miou") is not None:
                mious.append(m["miou"] * 100)
            print(f"{name} seed {seed}: ATE {ates[-1]:.2f} cm, tracking {track_ms[-1]:.0f} ms/frame", file=sys.stderr)
        rows.append(
            [
                name,
                " / ".join(f"{a:.2f}" for a in ates),
                f"{np.mean(ates):.2f}",
                f"{np.mean(track_ms):.0f}",
                f"{np.mean(mious):.1f}" if mious else "-",
            ]
        )
    headers = ["tracker", "ATE RMSE per seed (cm)", "mean ATE (cm)", "tracking ms/frame (mean)", "mIoU %"]
    return f"Seeds {seeds}:\n\n" + markdown_table(headers, rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("input", nargs="?", type=Path, help="dataset folder or MCAP bag (default: the synthetic room)")
    parser.add_argument("--preset", help="config preset (default: chosen from the dataset)")
    parser.add_argument("--max-frames", type=int, help="process at most N frames")
    parser.add_argument("--downscale", type=float, help="divide the image size by F (room default: 2 = 160x120)")
    parser.add_argument(
        "--trackers",
        nargs="+",
        default=["adam", "gauss_newton"],
        help="METHOD[:KEY=VALUE;...]: a tracking.method and overrides under tracking.",
    )
    parser.add_argument("--device", choices=["auto", "cpu", "cuda"], default="cpu")
    parser.add_argument("--driver", help="the tracker whose poses drive pass 1 (default: the preset's)")
    parser.add_argument("--seeds", nargs="+", type=int, default=[0], help="seeds of pass 2's runs")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--skip-runs", action="store_true", help="pass 1 only")
    parser.add_argument("--no-append", action="store_true", help="print only, do not append to BENCHMARKS.md")
    args = parser.parse_args()

    data = args.input or ensure_room(default_room_dir())
    downscale = args.downscale or (2.0 if args.input is None else 1.0)
    preset = args.preset or default_preset(data, "auto")
    overrides = [*args.overrides, f"device={args.device}"]
    config = load_config(preset, None, overrides)
    dataset = open_dataset(data, "auto", DatasetOptions(max_frames=args.max_frames, downscale=downscale))
    k = dataset.intrinsics
    driver = args.driver or config.tracking.method
    print(f"{dataset.name}: {len(dataset)} frames at {k.width}x{k.height}, preset {preset}", file=sys.stderr)
    configs = {spec: tracker_config(spec, preset, overrides) for spec in args.trackers}
    device = resolve_device(config.device)
    trackers = {spec: build_tracker(cfg.tracking, build_kernels(cfg.render, device)) for spec, cfg in configs.items()}
    side, truth = same_map_pass(dataset, config, trackers, driver if driver in trackers else args.trackers[0])
    body = (
        f"Pass 1: every tracker on the same {len(truth)} frames and maps (driven by `{driver}`), "
        f"same start pose:\n\n" + same_map_table(side, truth, args.trackers[0]) + "\n"
    )
    if not args.skip_runs:
        body += "\nPass 2: each tracker's own lockstep run. " + own_runs_table(dataset, configs, args.seeds)
    body += f"\n\nOverrides: {args.overrides or 'none'}.\n"
    print(body)
    if not args.no_append:
        append_section(f"Tracking: {dataset.name} {k.width}x{k.height}, {preset}", body)


if __name__ == "__main__":
    main()
