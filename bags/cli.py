"""``sgs-slam-bag``: convert dataset folders to MCAP bags, and describe bags."""

from __future__ import annotations

import argparse
import shutil
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from rosbags.rosbag2 import WriterError

from bags.errors import BagError
from bags.info import bag_info
from bags.writer import convert
from msg_adapters import AdapterError
from sgs_slam_core.cli import add_debug_flag, run_command
from sgs_slam_core.cli.args import IntRange
from sgs_slam_core.cli.run import default_preset
from sgs_slam_core.datasets import DatasetOptions, formats, open_dataset
from sgs_slam_core.datasets.base import Dataset
from sgs_slam_core.runner.progress import ProgressBar

__all__ = ["main"]

_FRAMES = IntRange(1)


def _convert(args: argparse.Namespace) -> int:
    out = args.out or args.input.with_name(args.input.name.rstrip("/") + "_bag")
    if out.exists():
        raise BagError(f"{out} exists; refusing to overwrite")
    dataset = open_dataset(
        args.input, args.format, DatasetOptions(max_frames=args.max_frames, downscale=args.downscale)
    )
    bar = ProgressBar(len(dataset), "convert")
    t0 = time.perf_counter()
    preset = default_preset(args.input, args.format)
    try:
        name = f"{dataset.name}/{args.input.name}"
        summary = convert(
            dataset,
            out,
            compress=args.compress == "zstd",
            dataset_name=name,
            progress=lambda done, _: bar.update(done),
            preset=preset,
        )
    except BaseException as err:
        shutil.rmtree(out, ignore_errors=True)  # a bag without its metadata is of no use; it did not exist before
        if isinstance(err, WriterError):
            raise BagError(f"cannot write the bag {out}: {err}") from err
        raise
    elapsed = time.perf_counter() - t0
    size_mib, rate = summary.bytes / 2**20, summary.frames / elapsed
    print(f"wrote {summary.frames} frames ({size_mib:.1f} MiB, {rate:.1f} frames/s) to {out} (preset {preset})")
    for line in _left_out(dataset, summary.frames, args):
        print(line)
    return 0


def _left_out(dataset: Dataset, written: int, args: argparse.Namespace) -> list[str]:
    """One line per reason why frames the folder lists are not in the bag."""
    lines = [f"left out {n} {why}" for why, n in getattr(dataset, "left_out", {}).items() if n]
    if args.max_frames is not None and written == args.max_frames:
        lines.append(f"stopped at --max-frames {args.max_frames}: later frames were not converted")
    return lines


def _info(args: argparse.Namespace) -> int:
    print(bag_info(args.bag).format())
    return 0


def build_parser() -> argparse.ArgumentParser:
    """Sub-commands convert and info."""
    parser = argparse.ArgumentParser(prog="sgs-slam-bag", description="Dataset folders <-> rosbag2 MCAP bags.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    c = sub.add_parser("convert", help="write a dataset folder as a rosbag2 MCAP bag")
    c.add_argument("input", type=Path, help="TUM, Replica, ScanNet or synthetic folder")
    c.add_argument("--format", default="auto", choices=["auto", *(f for f in formats() if f != "mcap")])
    c.add_argument("--out", type=Path, help="bag folder to create (default: INPUT_bag); never overwritten")
    c.add_argument("--max-frames", type=_FRAMES, help=f"convert at most N frames ({_FRAMES.bounds})")
    c.add_argument(
        "--downscale", type=float, default=1.0, help="divide width and height by this (as sgs-slam run --downscale)"
    )
    c.add_argument("--compress", choices=["zstd", "none"], default="zstd", help="MCAP chunk compression")
    c.set_defaults(func=_convert)
    i = sub.add_parser("info", help="topics, counts, duration, encodings and label table of a bag")
    i.add_argument("bag", type=Path)
    i.set_defaults(func=_info)
    add_debug_flag(parser, sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; errors are one line on stderr: exit 1 for bad input, 2 for usage, 70 for a bug."""
    return run_command("sgs-slam-bag", build_parser(), argv, (AdapterError,))


if __name__ == "__main__":
    sys.exit(main())
