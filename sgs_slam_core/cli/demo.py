"""``sgs-slam demo``: generate the built-in synthetic room (once) and run SLAM on it."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from sgs_slam_core.cli.args import IntRange
from sgs_slam_core.config import load_config
from sgs_slam_core.datasets import DatasetOptions, open_dataset
from sgs_slam_core.runner import format_table, run_offline
from sgs_slam_core.runner.progress import ProgressBar
from sgs_slam_core.synthetic import generate, preset_config

__all__ = ["DEMO_PRESET", "add_parser", "default_room_dir", "ensure_room", "run"]

DEMO_PRESET = "synthetic_fast"


def default_room_dir() -> Path:
    """Where the built-in room sequence is cached ($XDG_CACHE_HOME/sgs-slam/room)."""
    base = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    return base / "sgs-slam" / "room"


def ensure_room(data: Path) -> Path:
    """Generate the built-in 200-frame room (320x240) into ``data`` unless it is there; return ``data``."""
    if not (data / "traj.txt").is_file():
        print(f"generating the synthetic room into {data} ...", file=sys.stderr)
        bar = ProgressBar(200, "synth")
        generate(data, preset_config("room"), overwrite=True, progress=lambda done, _: bar.update(done))
    return data


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the sub-command."""
    p = sub.add_parser(
        "demo",
        help="generate the synthetic room (if needed) and run SLAM on it on the CPU",
        description=f"Runs preset {DEMO_PRESET} on the built-in 200-frame room at 160x120 and prints the metrics.",
    )
    p.add_argument("--out", type=Path, default=Path("demo_out"), help="run folder (default: demo_out, replaced)")
    p.add_argument("--data", type=Path, default=default_room_dir(), help="where the room sequence is kept")
    p.add_argument("--max-frames", type=IntRange(1), help="stop after N frames (>= 1)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Generate if missing, then run and print the table."""
    ensure_room(args.data)
    dataset = open_dataset(args.data, "replica", DatasetOptions(downscale=2.0, max_frames=args.max_frames))
    config = load_config(DEMO_PRESET)
    k = dataset.intrinsics
    print(f"room: {len(dataset)} frames at {k.width}x{k.height}, preset {DEMO_PRESET}", file=sys.stderr)
    provenance = {
        "input": str(args.data.resolve()),
        "format": "replica",
        "options": {"start": 0, "stride": 1, "max_frames": args.max_frames, "downscale": 2.0},
        "preset": DEMO_PRESET,
        "overrides": [],
        "command": "sgs-slam demo",
    }
    result = run_offline(dataset, config, args.out, overwrite=True, provenance=provenance)
    print(format_table(result.metrics))
    print(f"run folder: {args.out} (renders/, trajectory.png, map.ply)")
    return 0
