"""Bag benchmark: conversion and read throughput (frames/s, MB/s) for 640x480 RGB-D + label frames.

Source: the real TUM fr3/teddy sample (640x480) with a class-id image added per frame (depth bands,
so the semantic topic is written too). "convert (in memory)" feeds decoded frames to the writer, so
it measures the bag writer alone; "convert (from folder)" is ``sgs-slam-bag convert`` end to end,
PNG decoding included. "read" decodes every frame back with the bag reader ``sgs-slam run`` uses.

    python bench/bench_bags.py [--frames 100] [--repeats 3] [--no-append]
"""

from __future__ import annotations

import argparse
import dataclasses
import shutil
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bags import convert, open_bag
from bench.common import append_section, markdown_table
from sgs_slam_core.datasets import DatasetOptions, open_dataset
from sgs_slam_core.frame import Frame
from sgs_slam_core.geometry import Intrinsics
from sgs_slam_core.labels import LabelTable

TUM = Path(__file__).resolve().parents[2] / "shared" / "data" / "tum_fr3_teddy"


class MemoryDataset:
    """Decoded frames held in memory (the Dataset protocol), with class ids from depth bands."""

    name = "tum_fr3_teddy+labels"

    def __init__(self, frames: list[Frame]) -> None:
        self.frames = [dataclasses.replace(f, labels=np.minimum(f.depth * 4, 40).astype(np.int32)) for f in frames]

    @property
    def intrinsics(self) -> Intrinsics:
        return self.frames[0].intrinsics

    @property
    def label_table(self) -> LabelTable:
        return LabelTable.nyu40()

    @property
    def has_ground_truth(self) -> bool:
        return all(f.gt_c2w is not None for f in self.frames)

    @property
    def has_labels(self) -> bool:
        return True

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, index: int) -> Frame:
        return self.frames[index]


def best_of(repeats: int, job: Callable[[int], None]) -> float:
    """Fastest of ``repeats`` runs of ``job(repeat)`` in seconds (the machine is shared and noisy)."""
    times = []
    for r in range(repeats):
        t0 = time.perf_counter()
        job(r)
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--input", type=Path, default=TUM, help="TUM folder (default: the shared sample)")
    parser.add_argument("--frames", type=int, default=100, help="frames per bag")
    parser.add_argument("--repeats", type=int, default=3, help="runs per case; the fastest counts")
    parser.add_argument("--no-append", action="store_true", help="print only, do not append to BENCHMARKS.md")
    args = parser.parse_args()

    source = open_dataset(args.input, "tum", DatasetOptions(max_frames=args.frames))
    memory = MemoryDataset([source[i] for i in range(len(source))])
    n, k = len(memory), memory.intrinsics
    work = Path(tempfile.mkdtemp(prefix="bench_bags_"))
    rows = []
    try:
        for compress in (False, True):
            tag = "zstd" if compress else "none"

            def write(r: int, compress: bool = compress, tag: str = tag) -> None:
                convert(memory, work / f"mem_{tag}_{r}", compress=compress)

            t = best_of(args.repeats, write)
            size = sum(p.stat().st_size for p in (work / f"mem_{tag}_0").iterdir()) / 2**20
            rows.append([f"convert (in memory), {tag}", f"{n / t:.0f}", f"{size / t:.0f}", f"{size / n:.2f}"])

            def write_folder(r: int, compress: bool = compress, tag: str = tag) -> None:
                convert(
                    open_dataset(args.input, "tum", DatasetOptions(max_frames=n)), work / f"dir_{tag}_{r}", compress
                )

            t = best_of(args.repeats, write_folder)
            size_dir = sum(p.stat().st_size for p in (work / f"dir_{tag}_0").iterdir()) / 2**20
            rate = [f"{n / t:.0f}", f"{size_dir / t:.0f}", f"{size_dir / n:.2f}"]
            rows.append([f"convert (from folder, PNG decode), {tag}", *rate])

            def read(r: int, tag: str = tag) -> None:
                bag = open_bag(work / f"mem_{tag}_0")
                try:
                    for i in range(len(bag)):
                        frame = bag[i]
                        assert frame.labels is not None and frame.rgb.shape == (k.height, k.width, 3)
                finally:
                    bag.close()

            t = best_of(args.repeats, read)
            rows.append([f"read (bag reader, decode to Frame), {tag}", f"{n / t:.0f}", f"{size / t:.0f}", "-"])
    finally:
        shutil.rmtree(work, ignore_errors=True)
    table = markdown_table(["case", "frames/s", "MB/s", "MB/frame"], rows)
    body = (
        f"{n} frames at {k.width}x{k.height} (rgb8 + 16UC1 depth + 16UC1 labels + camera_info + pose + clock), "
        f"best of {args.repeats}. Targets: convert >= 100 frames/s uncompressed, read >= 300 frames/s.\n\n{table}\n"
    )
    print(body)
    if not args.no_append:
        append_section("Bags: MCAP conversion and read throughput", body)


if __name__ == "__main__":
    main()
