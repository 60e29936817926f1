"""The map kept on disk while it is made: what autosaves cost tracking, and how well a restart resumes.

Two measurements on a real RGB-D sequence:

- ``timing``: the sequence released live at its stamps into the pipeline (as ``sgs-slam run
  --realtime``), without autosaves and with a :class:`~sgs_slam_core.live.map_saver.MapSaver`
  saving every ``--period`` s (runs interleaved, ``--repeats`` each). Per run: frames tracked, the
  mean tracking time per frame, and (with autosaves) the mean over the frames whose tracking
  overlapped a save, the saves' size and time, and how long a snapshot held the workers. The
  target: tracking while a save writes within 1.2x of tracking without autosaves.
- ``resume``: lockstep, every frame. The uninterrupted run, then a run saved every
  ``--save-every`` frames and killed at ``--kill`` (the frames after its last save are lost with the
  process), restarted from the file ``--gap`` frames later (the camera moved on meanwhile) with the
  camera relocalized in the loaded map. The poses published before the kill and after the restart
  are aligned together to the ground truth (one SE(3)); the resumed part's RMSE under that alignment
  is compared with the uninterrupted run's over the same frames. Target: within 1.5x.

    python bench/bench_autosave.py timing ../shared/data/tum_fr3_teddy --downscale 4
    python bench/bench_autosave.py resume ../shared/data/tum_fr3_teddy --downscale 4 --kill 100
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import append_section, markdown_table
from sgs_slam_core.config import load_config
from sgs_slam_core.config.schema import SlamConfig
from sgs_slam_core.datasets import DatasetOptions, open_dataset
from sgs_slam_core.frame import Frame
from sgs_slam_core.live import SlamPipeline
from sgs_slam_core.live.map_saver import MapSaver
from sgs_slam_core.mapio import load_map, save_map
from sgs_slam_core.metrics.trajectory import umeyama
from sgs_slam_core.slam.system import Slam, TrackOutcome


@dataclass(frozen=True)
class LiveRun:
    """One live replay: tracking times (s) of the tracked frames, which overlapped a save, and the saves."""

    frames_in: int
    tracking_s: list[float]
    during_save: list[bool]
    saves: int
    save_mb: float
    save_ms: float  # mean snapshot + write
    hold_ms: float  # mean time a snapshot held the workers

    def row(self, name: str) -> list[object]:
        t = np.asarray(self.tracking_s)
        overlap = np.asarray(self.during_save, dtype=bool)
        during = f"{1e3 * t[overlap].mean():.1f} ({overlap.sum()})" if overlap.any() else "n/a"
        outside = f"{1e3 * t[~overlap].mean():.1f}" if overlap.any() else "n/a"
        saves = f"{self.saves} x {self.save_mb:.1f} MiB, {self.save_ms:.0f} ms, hold {self.hold_ms:.1f} ms"
        row = [name, f"{len(t)} / {self.frames_in}", f"{1e3 * t.mean():.1f}", during, outside]
        return [*row, saves if self.saves else "-"]


def live_run(frames: list[Frame], config: SlamConfig, period_s: float, work: Path) -> LiveRun:
    """Release ``frames`` at their stamps into a live pipeline; with ``period_s`` > 0, save the map that often."""
    slam = Slam(config)
    slam.prepare(lambda _: None)
    pipeline = SlamPipeline(slam, lockstep=False, log=print)
    tracked: list[tuple[float, float]] = []  # (end, duration) of each frame's tracking, monotonic s
    pipeline.pose_listeners.append(lambda _f, o: tracked.append((time.monotonic(), o.time_s)))
    saver = MapSaver(work / "autosave.sgsmap", pipeline.map_file, turn=pipeline.background_turn)
    windows: list[tuple[float, float]] = []
    stats = []
    stop = threading.Event()

    def autosave() -> None:  # MapSaver's own loop, timed: when each save ran
        while not stop.wait(period_s):
            t0 = time.monotonic()
            if saver.save(background=True).saved:
                windows.append((t0, time.monotonic()))
                s = saver.stats
                stats.append((s.last_bytes, s.last_snapshot_s + s.last_write_s, pipeline.stats.snapshot_hold_s))

    thread = threading.Thread(target=autosave, daemon=True) if period_s > 0 else None
    start = time.monotonic()
    if thread is not None:
        thread.start()
    t0_ns = frames[0].stamp_ns
    for f in frames:
        delay = start + (f.stamp_ns - t0_ns) / 1e9 - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        pipeline.submit_frame(f)
    pipeline.wait_idle(120.0)
    stop.set()
    if thread is not None:
        thread.join()
    pipeline.shutdown()
    durations = [d for _, d in tracked]
    overlap = [any(a < end and begin < b for a, b in windows) for end, d in tracked for begin in [end - d]]
    sizes, totals, holds = zip(*stats, strict=True) if stats else ((0,), (0.0,), (0.0,))
    return LiveRun(
        len(frames),
        durations,
        overlap,
        len(stats),
        float(np.mean(sizes)) / 2**20,
        1e3 * float(np.mean(totals)),
        1e3 * float(np.mean(holds)),
    )


def timing(args: argparse.Namespace, frames: list[Frame], config: SlamConfig) -> str:
    live = config.for_live()
    rows, without, during, outside = [], [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.repeats):
            for period in (0.0, args.period):
                run = live_run(frames, live, period, Path(tmp))
                name = f"autosave every {period:g} s" if period else "no autosave"
                rows.append(run.row(f"{name} (run {r + 1})"))
                print(rows[-1], flush=True)
                if period:
                    during += [t for t, o in zip(run.tracking_s, run.during_save, strict=True) if o]
                    outside += [t for t, o in zip(run.tracking_s, run.during_save, strict=True) if not o]
                else:
                    without += run.tracking_s
    ratio = np.mean(during) / np.mean(without) if during and without else float("nan")
    same_runs = np.mean(during) / np.mean(outside) if during and outside else float("nan")
    headers = ["run", "tracked", "tracking ms/frame", "while a save ran (frames)", "the other frames"]
    table = markdown_table([*headers, "saves (size, time, hold)"], rows)
    return (
        f"{args.input.name}, {frames[0].intrinsics.width}x{frames[0].intrinsics.height}, live at the recorded "
        f"stamps, preset {args.preset}; tracking time per frame in ms.\n\n{table}\n\nTracking while a save ran: "
        f"{ratio:.2f}x the runs without autosave (target: at most 1.2x); {same_runs:.2f}x the other frames of the "
        "same runs.\n"
    )


def lockstep(slam: Slam, frames: list[Frame], save_every: int = 0, path: Path | None = None) -> dict[int, np.ndarray]:
    """Process ``frames`` one by one; the published pose of each (by stamp); save every ``save_every`` frames."""
    poses = {}
    for n, f in enumerate(frames, start=1):
        outcome: TrackOutcome = slam.process(f).track
        poses[f.stamp_ns] = np.asarray(outcome.c2w)
        if save_every and n % save_every == 0 and path is not None:
            slam.refresh_labels()
            save_map(path, slam.to_map_file())
    return poses


def rmse_of(est: dict[int, np.ndarray], gt: dict[int, np.ndarray], stamps: list[int], part: list[int]) -> float:
    """RMSE (m) of the camera centres of ``part`` after one SE(3) alignment of all ``stamps``."""
    p = np.stack([est[s][:3, 3] for s in stamps])
    q = np.stack([gt[s][:3, 3] for s in stamps])
    r, t, _ = umeyama(p, q)
    index = {s: i for i, s in enumerate(stamps)}
    rows = [index[s] for s in part]
    err = (p[rows] @ r.T + t) - q[rows]
    return float(np.sqrt((err**2).sum(axis=1).mean()))


def resume(args: argparse.Namespace, frames: list[Frame], config: SlamConfig) -> str:
    gt = {f.stamp_ns: f.gt_c2w for f in frames}
    whole = lockstep(Slam(config), frames)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "map.sgsmap"
        first = lockstep(Slam(config), frames[: args.kill], args.save_every, path)
        saved = load_map(path)  # what the killed process left: its last autosave
        slam = Slam(config)
        slam.load_map(saved, relocalize=True)
        after = frames[args.kill + args.gap :]
        states: list[str] = []
        second = {}
        for f in after:
            outcome = slam.process(f).track
            second[f.stamp_ns] = np.asarray(outcome.c2w)
            states.append(outcome.state)
    found = states.index("relocalized") if "relocalized" in states else None
    est = {**first, **second}
    stamps = sorted(s for s in est if gt.get(s) is not None)  # frames with ground truth
    part = [s for s in stamps if s in second]
    resumed = rmse_of(est, gt, stamps, part)
    reference = rmse_of(whole, gt, stamps, part)
    overall = rmse_of(est, gt, stamps, stamps)
    ratio = resumed / reference
    rows = [
        ["uninterrupted", len(whole), f"{100 * reference:.2f}", f"{100 * rmse_of(whole, gt, stamps, stamps):.2f}"],
        ["killed and resumed", len(est), f"{100 * resumed:.2f}", f"{100 * overall:.2f}"],
    ]
    table = markdown_table(["run", "poses", "ATE of the resumed frames (cm)", "ATE of both parts (cm)"], rows)
    saved_frames = len(saved.trajectory)
    found_text = "never" if found is None else f"at its {found + 1}. frame"
    return (
        f"{args.input.name}, {frames[0].intrinsics.width}x{frames[0].intrinsics.height}, lockstep, preset "
        f"{args.preset}: saved every {args.save_every} frames, killed after frame {args.kill} (last save: "
        f"{saved_frames} frames), restarted {args.gap} frames later; relocalized {found_text}.\n\n{table}\n\n"
        f"Resumed part: {ratio:.2f}x the uninterrupted run's ATE over the same frames (target: at most 1.5x).\n"
    )


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("what", choices=("timing", "resume"))
    p.add_argument("input", type=Path, help="an RGB-D dataset folder with ground truth (TUM layout)")
    p.add_argument("--downscale", type=float, default=4.0)
    p.add_argument("--preset", default="tum")
    p.add_argument("--max-frames", type=int, default=None)
    p.add_argument("--period", type=float, default=1.0, help="timing: seconds between autosaves")
    p.add_argument("--repeats", type=int, default=2, help="timing: runs of each (interleaved)")
    p.add_argument("--save-every", type=int, default=30, help="resume: frames between saves")
    p.add_argument("--kill", type=int, default=100, help="resume: frames processed before the kill")
    p.add_argument("--gap", type=int, default=15, help="resume: frames missed while the process restarts")
    p.add_argument("--no-append", action="store_true")
    args = p.parse_args()
    options = DatasetOptions(downscale=args.downscale, max_frames=args.max_frames)
    dataset = open_dataset(args.input, options=options)
    frames = [dataset[i] for i in range(len(dataset))]
    config = load_config(args.preset)
    body = timing(args, frames, config) if args.what == "timing" else resume(args, frames, config)
    print(body)
    if not args.no_append:
        title = "Autosave: tracking while the map is written" if args.what == "timing" else "Resume after a kill"
        append_section(title, body)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
