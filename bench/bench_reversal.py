"""Tracking through reversals: the room's orbit played there and back, every ``--stride``-th frame.

A live camera that turns back is the motion prior's worst case: constant velocity predicts the
camera going on, and with frames dropped (the stride; a camera at 30 Hz tracked at 10 Hz is stride
3) the start is several frames' rotation off. This replays the orbit (``--loop-frames`` frames,
1.5 degrees apart, forwards then backwards) through ``Slam.process`` in lockstep, keeping every
``--stride``-th frame with 30 Hz stamps, and counts the frames the guard rejected, the longest run
of them, and the position error of the accepted frames. Prints a table; appends it to BENCHMARKS.md.

    python bench/bench_reversal.py [--width 320 --height 240] [--loop-frames 120] [--loops 2] [--stride 3 6]
        [--set key=value ...] [--no-append]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.bench_longrun import order
from bench.common import append_section, markdown_table
from sgs_slam_core.config import load_config
from sgs_slam_core.config.schema import SlamConfig
from sgs_slam_core.datasets import open_dataset
from sgs_slam_core.datasets.base import Dataset
from sgs_slam_core.slam.system import Slam
from sgs_slam_core.synthetic import SynthConfig, generate


@dataclass(frozen=True)
class ReversalRun:
    """One stride's run: what the guard did and how far off the accepted poses were."""

    stride: int
    frames: int  # frames processed
    failed: int  # rejected by the guard
    longest_loss: int  # longest run of consecutive rejected frames
    first_failure: int | None  # stream position of the first rejected frame
    median_error_cm: float  # camera-centre error of the accepted frames (the first frame's pose is the origin)
    max_error_cm: float


def replay(dataset: Dataset, config: SlamConfig, stride: int, loops: float) -> ReversalRun:
    """Process every ``stride``-th frame of ``loops`` loops there and back; what the guard did."""
    period = 2 * (len(dataset) - 1)
    slam = Slam(config, dataset.label_table)
    origin = np.linalg.inv(dataset[0].gt_c2w)
    failed = streak = longest = 0
    first, errors = None, []
    positions = order(len(dataset), round(loops * period))
    for i in range(0, len(positions), stride):
        frame = replace(dataset[positions[i]], stamp_ns=10**9 + i * 33_333_333)
        step = slam.process(frame)
        if step.track.failed:
            failed, streak = failed + 1, streak + 1
            longest = max(longest, streak)
            first = i if first is None else first
            continue
        streak = 0
        errors.append(np.linalg.norm(step.c2w[:3, 3] - (origin @ frame.gt_c2w)[:3, 3]))
    err = 100 * np.asarray(errors) if errors else np.array([np.nan])
    count = -(-len(positions) // stride)
    return ReversalRun(stride, count, failed, longest, first, float(np.median(err)), float(err.max()))


def main() -> int:
    """Render the orbit, replay it at each stride, report."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--width", type=int, default=320)
    p.add_argument("--height", type=int, default=240)
    p.add_argument("--loop-frames", type=int, default=120, help="orbit frames rendered (1.5 degrees apart)")
    p.add_argument("--loops", type=float, default=2.0, help="loops there and back")
    p.add_argument("--stride", type=int, nargs="+", default=[3, 6], help="keep every N-th frame")
    p.add_argument("--preset", default="synthetic")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config overrides")
    p.add_argument("--no-append", action="store_true", help="print only; leave BENCHMARKS.md alone")
    args = p.parse_args()
    live = ["device=cpu", "tracking.method=gauss_newton", "mapping.iterations=5", "mapping.prune_iterations=[0,2]"]
    config = load_config(args.preset, overrides=[*live, *args.set])
    with tempfile.TemporaryDirectory() as tmp:
        orbit = SynthConfig(width=args.width, height=args.height, frames=args.loop_frames)
        dataset = open_dataset(generate(Path(tmp) / "orbit", orbit))
        runs = []
        for stride in args.stride:
            runs.append(replay(dataset, config, stride, args.loops))
            print(runs[-1], flush=True)
    table = markdown_table(
        ["stride", "frames", "rejected", "longest loss", "first rejected at", "error cm (median / max)"],
        [
            [
                r.stride,
                r.frames,
                r.failed,
                r.longest_loss,
                "-" if r.first_failure is None else r.first_failure,
                f"{r.median_error_cm:.1f} / {r.max_error_cm:.1f}",
            ]
            for r in runs
        ],
    )
    body = (
        f"The room's orbit ({args.loop_frames} frames at {args.width}x{args.height}, 1.5 degrees apart) there "
        f"and back for {args.loops:g} loops, every N-th frame with 30 Hz stamps, through `Slam.process` "
        f"(preset `{args.preset}`, Gauss-Newton tracking, 5 mapping iterations; overrides: "
        f"{args.set or 'none'}). A reversal comes at stream positions {args.loop_frames - 1} and "
        f"{2 * (args.loop_frames - 1)}.\n\n{table}\n"
    )
    print(body)
    if not args.no_append:
        append_section(f"Reversals: room orbit {args.width}x{args.height}, strides {args.stride}", body)
    return 0


if __name__ == "__main__":
    sys.exit(main())
