"""``sgs-slam-bag``: convert dataset folders to MCAP bags, and describe bags."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from bags.errors import BagError
from bags.info import bag_info
from bags.writer import convert
from sgs_slam_core.cli import run_command
from sgs_slam_core.cli.progress import ProgressBar
from sgs_slam_core.cli.run import default_preset
from sgs_slam_core.datasets import FORMATS, DatasetOptions, open_dataset

__all__ = ["main"]


def _convert(args: argparse.Namespace) -> int:
    out = args.out or args.input.with_name(args.input.name.rstrip("/") + "_bag")
    if out.exists():
        raise BagError(f"{out} exists; refusing to overwrite")
    dataset = open_dataset(args.input, args.format, DatasetOptions(max_frames=args.max_frames))
    bar = ProgressBar(len(dataset), "convert")
    t0 = time.perf_counter()
    preset = default_preset(args.input, args.format)
    summary = convert(dataset, out, compress=args.compress == "zstd", dataset_name=f"{dataset.name}/{args.input.name}",
                      progress=lambda done, _: bar.update(done), preset=preset)  # fmt: skip
    elapsed = time.perf_counter() - t0
    size_mib, rate = summary.bytes / 2**20, summary.frames / elapsed
    print(f"wrote {summary.frames} frames ({size_mib:.1f} MiB, {rate:.1f} frames/s) to {out} (preset {preset})")
    return 0


def _info(args: argparse.Namespace) -> int:
    print(bag_info(args.bag).format())
    return 0


def build_parser() -> argparse.ArgumentParser:
    """Sub-commands convert and info."""
    parser = argparse.ArgumentParser(prog="sgs-slam-bag", description="Dataset folders <-> rosbag2 MCAP bags.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    c = sub.add_parser("convert", help="write a dataset folder as a rosbag2 MCAP bag")
    c.add_argument("input", type=Path, help="TUM, Replica, ScanNet or synthetic folder")
    c.add_argument("--format", default="auto", choices=["auto", *(f for f in FORMATS if f != "mcap")])
    c.add_argument("--out", type=Path, help="bag folder to create (default: INPUT_bag); never overwritten")
    c.add_argument("--max-frames", type=int, help="convert at most N frames")
    c.add_argument("--compress", choices=["zstd", "none"], default="zstd", help="MCAP chunk compression")
    c.set_defaults(func=_convert)
    i = sub.add_parser("info", help="topics, counts, duration, encodings and label table of a bag")
    i.add_argument("bag", type=Path)
    i.set_defaults(func=_info)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; errors are one line on stderr and exit code 1."""
    return run_command("sgs-slam-bag", build_parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
