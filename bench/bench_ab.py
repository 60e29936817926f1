"""Paired speed comparison of two checkouts' SLAM, frame by frame, in one run.

Two worker processes (``bench/ab_worker.py``), one per checkout, run the same dataset with the same
preset. Frame i is processed by one worker while the other waits, then by the other (the order
alternates per frame), so both see the same machine at nearly the same moment: on a VM whose speed
swings by a third within minutes, the ratio stays meaningful where absolute times do not. Reports time
per frame (mean and median of tracking + mapping; loading is not timed), the ratio new/base and
each side's ATE, and appends the table to BENCHMARKS.md.

    python bench/bench_ab.py --base /work/base [INPUT] [--downscale F] [--max-frames N] [--set K=V]

``--base`` is a checkout of the baseline commit (``git worktree add /work/base 4c681e6``).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import REPO, append_section, markdown_table
from sgs_slam_core.cli.demo import default_room_dir, ensure_room
from sgs_slam_core.cli.run import default_preset


@dataclass
class Side:
    """One checkout's worker and what it measured."""

    name: str
    checkout: Path
    proc: subprocess.Popen
    totals: list[float] = field(default_factory=list)
    tracking: list[float] = field(default_factory=list)
    finish: dict = field(default_factory=dict)

    def ask(self, cmd: dict) -> dict:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(json.dumps(cmd) + "\n")
        self.proc.stdin.flush()
        return self.read()

    def read(self) -> dict:
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        if not line:
            raise SystemExit(f"{self.name} worker ({self.checkout}) died; see its stderr above")
        return json.loads(line)


def _commit(checkout: Path) -> str:
    cmd = ["git", "rev-parse", "--short", "HEAD"]
    out = subprocess.run(cmd, cwd=checkout, capture_output=True, text=True, check=False)
    return out.stdout.strip() or "unknown"


def _start(name: str, checkout: Path, worker_args: list[str]) -> Side:
    env = dict(os.environ, PYTHONPATH=str(checkout))
    cmd = [sys.executable, str(REPO / "bench" / "ab_worker.py"), *worker_args]
    proc = subprocess.Popen(cmd, cwd=checkout, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    return Side(name, checkout, proc)


def _report(sides: list[Side], frames: int, what: str, overrides: list[str]) -> str:
    """The markdown table and ratios of both sides' per-frame times (``what``: the input and settings)."""
    base, new = (np.asarray(s.totals) * 1e3 for s in sides)
    track_base, track_new = (np.asarray(s.tracking) * 1e3 for s in sides)
    rows = [
        [
            s.name,
            _commit(s.checkout),
            f"{np.mean(t):.0f}",
            f"{np.median(t):.0f}",
            f"{np.median(tr):.1f}",
            f"{s.finish['num_gaussians']:,}",
            f"{s.finish['ate_rmse_m'] * 100:.2f}" if s.finish["ate_rmse_m"] is not None else "-",
        ]
        for s, t, tr in zip(sides, (base, new), (track_base, track_new), strict=True)
    ]
    ratio_mean, ratio_median = np.mean(new) / np.mean(base), np.median(new) / np.median(base)
    headers = ["side", "commit", "ms/frame (mean)", "ms/frame (median)", "tracking ms (median)", "Gaussians", "ATE cm"]
    body = markdown_table(headers, rows)
    body += (
        f"\n\nTracking time new/base: {np.median(track_new) / np.median(track_base):.2f}x (medians), "
        f"{np.mean(track_new) / np.mean(track_base):.2f}x (means)."
        f"\n\nTime per frame new/base: **{ratio_mean:.2f}x** (means), {ratio_median:.2f}x (medians); per-frame "
        f"ratios p10/p50/p90 {np.percentile(new / base, 10):.2f} / {np.percentile(new / base, 50):.2f} / "
        f"{np.percentile(new / base, 90):.2f}. {frames} frames of {what}, "
        f"overrides {overrides or 'none'}; frames interleaved (order alternating), "
        "tracking + mapping timed, loading not.\n"
    )
    return body


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("input", nargs="?", type=Path, help="dataset folder (default: the synthetic room)")
    parser.add_argument("--base", type=Path, required=True, help="checkout of the baseline commit")
    parser.add_argument("--new", type=Path, default=REPO, help="checkout to compare (default: this one)")
    parser.add_argument("--preset", help="config preset (default: chosen from the dataset)")
    parser.add_argument("--downscale", type=float, help="divide the image size by F (room default: 2 = 160x120)")
    parser.add_argument("--max-frames", type=int)
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--no-append", action="store_true")
    args = parser.parse_args()
    data = args.input or ensure_room(default_room_dir())
    downscale = args.downscale or (2.0 if args.input is None else 1.0)
    preset = args.preset or default_preset(data, "auto")
    worker_args = [
        str(data.resolve()),
        "--preset",
        preset,
        "--downscale",
        str(downscale),
        *(["--max-frames", str(args.max_frames)] if args.max_frames else []),
        *[a for o in [*args.overrides, "device=cpu"] for a in ("--set", o)],
    ]
    sides = [_start("base", args.base.resolve(), worker_args), _start("new", args.new.resolve(), worker_args)]
    frames = min(side.read()["frames"] for side in sides)
    for i in range(frames):
        for side in sides if i % 2 == 0 else sides[::-1]:
            reply = side.ask({"frame": i})
            side.totals.append(reply["total_s"])
            side.tracking.append(reply["track_s"])
        if i % 10 == 0:
            print(
                f"frame {i}/{frames}: " + ", ".join(f"{s.name} {1e3 * s.totals[-1]:.0f} ms" for s in sides),
                file=sys.stderr,
            )
    for side in sides:
        side.finish = side.ask({"finish": True})
        side.proc.wait(timeout=60)
    body = _report(sides, frames, f"{data.name}, preset {preset}, downscale {downscale}", args.overrides)
    print(body)
    if not args.no_append:
        append_section(f"A/B: {data.name} x{downscale:g}, {preset}, new vs {_commit(args.base)}", body)


if __name__ == "__main__":
    main()
