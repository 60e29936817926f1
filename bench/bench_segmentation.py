"""Segmentation benchmark: SegFormer-b0 (ADE20K classes, mapped to NYU40) per frame on this machine.

Times ``Segmenter.__call__`` (normalise, forward, upsample, argmax, NYU40 lookup: all that
``segmentation_node`` does per image besides the message copy) at the given sizes, with random
weights (the same architecture and cost as the pretrained b0; nothing is downloaded).

    python bench/bench_segmentation.py [--sizes 320x240 640x480] [--frames 20] [--no-append]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import append_section, markdown_table
from sgs_slam_core.segmentation import Segmenter


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", nargs="+", default=["320x240", "640x480"])
    p.add_argument("--frames", type=int, default=20)
    p.add_argument("--device", default="cpu")
    p.add_argument("--no-append", action="store_true")
    args = p.parse_args()
    seg = Segmenter.random(args.device)
    rng = np.random.default_rng(0)
    rows = []
    for size in args.sizes:
        w, h = (int(v) for v in size.split("x"))
        rgb = rng.integers(0, 255, (h, w, 3), dtype=np.uint8)
        seg(rgb)  # warm-up (allocations, kernels)
        times = []
        for _ in range(args.frames):
            t0 = time.perf_counter()
            seg(rgb)
            times.append(time.perf_counter() - t0)
        med = statistics.median(times)
        rows.append([size, f"{1e3 * med:.0f}", f"{1e3 * min(times):.0f}", f"{1 / med:.1f}"])
        print(" | ".join(rows[-1]), flush=True)
    table = markdown_table(["size", "median ms", "best ms", "frames/s (median)"], rows)
    print(table)
    if not args.no_append:
        note = (
            f"SegFormer-b0 (ADE20K, 150 classes -> NYU40), {args.frames} frames per size on {args.device} "
            f"({torch.get_num_threads()} torch threads), random weights (the pretrained model's cost)"
        )
        append_section("Segmentation: segmentation_node's model per frame", note + "\n\n" + table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
