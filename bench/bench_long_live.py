"""Live for minutes: the share of frames tracked and the time per frame, tenth by tenth of a long run.

``sgs-slam run --realtime`` on a long input, then per tenth of the stream (by frame index): the share
of the frames sent that were tracked (a frame dropped while the tracker was busy, or tracked while
lost, is not), the mean tracking time of the tracked ones, and the last tenth's time over the
first's. A slope in either shows at a glance in the plot written beside the table.

Inputs:

- a dataset folder at its recorded stamps (a TUM sequence of >= 20 s), or
- ``--loop-s S``: a generated scene's frames played there and back until ``S`` seconds at
  ``--rate-hz`` (no folder given: the built-in synthetic room's 200 frames).

    python bench/bench_long_live.py /path/to/tum_fr1_xyz --downscale 4 [--repeats 2]
    python bench/bench_long_live.py --loop-s 120 --rate-hz 30 --downscale 2
"""

from __future__ import annotations

import argparse
import csv
import itertools
import json
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import REPO, append_section, commit, markdown_table
from bench.plot import Series, line_panel, save_panels
from sgs_slam_core.cli.demo import default_room_dir, ensure_room

TENTHS = 10
COLORS = [(200, 90, 30), (40, 140, 230), (60, 170, 60), (170, 60, 170)]  # BGR
# Files of one frame in a generated (synthetic/Replica-layout) scene: folder, name prefix.
_FRAME_FILES = (("frames", "frame"), ("depths", "depth"), ("semantic_ids", "semantic_id"),
                ("semantic_colors", "semantic_color"))  # fmt: skip


@dataclass(frozen=True)
class Tenths:
    """One run, tenth by tenth of the frames sent."""

    tracked_pct: np.ndarray  # [10] % of the frames sent in each tenth that were tracked (not lost)
    track_ms: np.ndarray  # [10] mean tracking time of those frames (ms)
    frames: int
    tracked: int
    ate_cm: float

    @property
    def growth(self) -> float:
        """Tracking time in the last tenth over the first."""
        return float(self.track_ms[-1] / self.track_ms[0])


def tenths(run_dir: Path) -> Tenths:
    """Read ``frames.csv`` and ``metrics.json`` of a run."""
    metrics = json.loads((run_dir / "metrics.json").read_text())
    frames = int(metrics["frames_in"])
    with (run_dir / "frames.csv").open() as f:
        rows = [r for r in csv.DictReader(f) if r["tracking_state"] != "lost"]
    index = np.array([int(r["dataset_index"]) for r in rows])  # [N]
    ms = np.array([float(r["track_ms"]) for r in rows])  # [N]
    edges = np.linspace(0, frames, TENTHS + 1).round().astype(int)
    share, mean_ms = np.zeros(TENTHS), np.zeros(TENTHS)
    for i, (a, b) in enumerate(itertools.pairwise(edges)):
        inside = (index >= a) & (index < b)
        share[i] = 100 * inside.sum() / max(b - a, 1)
        timed = inside & (index > 0)  # the first frame is only initialised, not tracked
        mean_ms[i] = ms[timed].mean() if timed.any() else float("nan")
    return Tenths(share, mean_ms, frames, len(rows), 100 * float(metrics.get("ate_rmse_m") or float("nan")))


def looped_copy(source: Path, out: Path, count: int) -> Path:
    """``count`` frames of the generated scene ``source`` there and back, its images linked, as a scene folder."""
    if not (source / "frames").is_dir():
        raise SystemExit(f"bench_long_live: --loop-s takes a generated scene (frames/, traj.txt); {source} is not one")
    total = len(list((source / "frames").iterdir()))
    period = [*range(total), *range(total - 2, 0, -1)]
    order = [period[i % len(period)] for i in range(count)]
    for folder, prefix in _FRAME_FILES:
        if not (source / folder).is_dir():
            continue
        (out / folder).mkdir(parents=True)
        suffix = next((source / folder).iterdir()).suffix
        for i, j in enumerate(order):
            (out / folder / f"{prefix}{i:06d}{suffix}").symlink_to(source / folder / f"{prefix}{j:06d}{suffix}")
    poses = (source / "traj.txt").read_text().splitlines()
    (out / "traj.txt").write_text("\n".join(poses[j] for j in order) + "\n")
    for name in ("camera.yaml", "labels.yaml", "synthetic.yaml"):
        if (source / name).is_file():
            (out / name).write_bytes((source / name).read_bytes())
    return out


def sgs_run(source: Path, out: Path, args: argparse.Namespace) -> None:
    """``sgs-slam run --realtime`` on ``source`` into ``out``."""
    cmd = [sys.executable, "-m", "sgs_slam_core.cli", "run", str(source), "--out", str(out), "--overwrite", "--quiet"]
    cmd += ["--downscale", str(args.downscale), "--realtime", str(args.rate_hz) if args.loop_s else "stamps"]
    cmd += ["--preset", args.preset] if args.preset else []
    for item in args.overrides:
        cmd += ["--set", item]
    proc = subprocess.run(cmd, check=False, capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"bench_long_live: {' '.join(cmd)} failed:\n{proc.stderr[-2000:]}")


def report(runs: list[Tenths], what: str, plot_path: Path) -> str:
    """Markdown: a row per run and tenth, the plot below."""
    headers = ["run", "tracked", *[f"{10 * i}-{10 * (i + 1)} %" for i in range(TENTHS)], "last / first", "ATE cm"]
    rows = []
    for i, r in enumerate(runs, 1):
        rows.append([f"{i}: tracked %", f"{r.tracked} / {r.frames}", *[f"{v:.0f}" for v in r.tracked_pct], "", ""])
        rows.append([f"{i}: tracking ms", "", *[f"{v:.1f}" for v in r.track_ms], f"{r.growth:.2f}", f"{r.ate_cm:.2f}"])
    worst = min(float(r.tracked_pct.min()) for r in runs)
    growth = max(r.growth for r in runs)
    return (
        f"{what}. Every tenth at least {worst:.0f} % tracked (target: 90 %); tracking time in the last "
        f"tenth at most {growth:.2f}x the first (target: 1.15x).\n\n"
        + markdown_table(headers, rows)
        + f"\n\n![long live run]({plot_path.relative_to(REPO).as_posix()})\n"
    )


def plot(runs: list[Tenths], path: Path, title: str) -> None:
    """Two panels over the tenths: tracked % and tracking ms, a line per run."""
    share = [Series(f"run {i}", r.tracked_pct, COLORS[(i - 1) % 4]) for i, r in enumerate(runs, 1)]
    ms = [Series(f"run {i}", r.track_ms, COLORS[(i - 1) % 4]) for i, r in enumerate(runs, 1)]
    x = "tenth of the run"
    save_panels(path, [line_panel(share, f"{title}: frames tracked", "% of frames sent", x_label=x),
                       line_panel(ms, f"{title}: tracking time", "ms per tracked frame", x_label=x)])  # fmt: skip


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("input", nargs="?", type=Path, help="dataset folder (default with --loop-s: the synthetic room)")
    p.add_argument("--loop-s", type=float, default=0, help="play the frames there and back for S seconds (0: once)")
    p.add_argument("--rate-hz", type=float, default=30, help="with --loop-s: the camera's rate")
    p.add_argument("--downscale", type=float, default=4)
    p.add_argument("--preset", help="config preset (default: chosen from the dataset)")
    p.add_argument("--repeats", type=int, default=1)
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    p.add_argument("--no-append", action="store_true", help="print only; do not append to BENCHMARKS.md")
    args = p.parse_args()
    if args.input is None and not args.loop_s:
        p.error("give a dataset folder, or --loop-s to loop the synthetic room")
    source = args.input or ensure_room(default_room_dir())
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        if args.loop_s:
            count = round(args.loop_s * args.rate_hz)
            source = looped_copy(source.resolve(), work / f"{source.name}_looped", count)
        for i in range(args.repeats):
            sgs_run(source, work / f"run{i}", args)
            runs.append(tenths(work / f"run{i}"))
            r = runs[-1]
            print(f"run {i + 1}: {r.tracked} / {r.frames} tracked, growth {r.growth:.2f}", flush=True)
    name = (args.input.name if args.input else "room") + (f"_looped{args.loop_s:g}s" if args.loop_s else "")
    plot_path = REPO / "bench" / "results" / f"long_live_{name}_{commit().split('+')[0]}.png"
    plot(runs, plot_path, name)
    rate = f"looped there and back for {args.loop_s:g} s at {args.rate_hz:g} Hz" if args.loop_s else "at its stamps"
    what = f"`{name}` ({runs[0].frames} frames {rate}, image size / {args.downscale:g}), `--realtime`"
    body = report(runs, what, plot_path)
    print(body)
    if not args.no_append:
        append_section(f"Long live run: {name}", body)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
