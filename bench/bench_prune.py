"""Pruning the mapping optimiser: rows gathered by index against each tensor indexed by the mask.

``GaussianOptimizer.prune`` slices every parameter and both Adam moments (and the labels) to the
kept rows after a mapping job's first step, i.e. on every live job. Both ways are timed in one run,
alternating, on a map of the size a live TUM run at 160x120 ends with, after one Adam step.

    python bench/bench_prune.py [--gaussians 46000] [--removed 0.01] [--repeats 200] [--no-append]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import append_section, markdown_table
from sgs_slam_core.config.sections import MappingSettings
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.slam.adam import AdamMoments
from sgs_slam_core.slam.optimizer import GaussianOptimizer


def stepped_optimizer(n: int, semantic: int) -> GaussianOptimizer:
    """An isotropic map of ``n`` Gaussians whose optimiser made one step (the moments exist)."""
    g = torch.Generator().manual_seed(0)
    gm = GaussianMap(
        means=torch.randn(n, 3, generator=g),
        log_scales=torch.randn(n, 1, generator=g),
        logit_opacities=torch.randn(n, generator=g),
        colors=torch.rand(n, 3, generator=g),
        semantics=torch.rand(n, semantic, generator=g),
        labels=torch.zeros(n, dtype=torch.long),
        birth_frame=torch.zeros(n, dtype=torch.long),
    )
    opt = GaussianOptimizer(gm, MappingSettings())
    sum(p.sum() for p in opt.params.values()).backward()
    opt.step()
    return opt


def prune_by_mask(opt: GaussianOptimizer, keep: torch.Tensor) -> None:
    """The way before (8d0a4bd): every tensor and moment indexed by the boolean mask, parameters copied once more."""
    for name in opt.names:
        opt.params[name] = opt.params[name].detach()[keep].clone().requires_grad_(True)
        s = opt.adam.state[name]
        opt.adam.state[name] = AdamMoments(s.exp_avg[keep], s.exp_avg_sq[keep], s.step)
    opt._labels, opt._birth, opt._weight = opt._labels[keep], opt._birth[keep], opt._weight[keep]


def time_ms(n: int, semantic: int, removed: float, repeats: int) -> tuple[list[float], list[float]]:
    """Per-prune ms of the mask way and the index way, alternating on fresh optimisers."""
    keep = torch.rand(n, generator=torch.Generator().manual_seed(1)) >= removed
    mask_ms, index_ms = [], []
    for i in range(2 * repeats):
        opt = stepped_optimizer(n, semantic)
        t0 = time.perf_counter()
        if i % 2:
            opt.prune(keep)
        else:
            prune_by_mask(opt, keep)
        (index_ms if i % 2 else mask_ms).append(1e3 * (time.perf_counter() - t0))
    return mask_ms, index_ms


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--gaussians", type=int, default=46000)
    p.add_argument("--semantic", type=int, default=3, help="semantic channels (3: colour mode)")
    p.add_argument("--removed", type=float, default=0.01, help="fraction of the Gaussians pruned")
    p.add_argument("--repeats", type=int, default=200)
    p.add_argument("--no-append", action="store_true", help="print only, do not append to BENCHMARKS.md")
    args = p.parse_args()
    mask_ms, index_ms = time_ms(args.gaussians, args.semantic, args.removed, args.repeats)
    m, i = float(np.median(mask_ms)), float(np.median(index_ms))
    table = markdown_table(
        ["way", "ms per prune (median)", "p10", "p90"],
        [
            [
                "mask indexing (before)",
                f"{m:.3f}",
                f"{np.percentile(mask_ms, 10):.3f}",
                f"{np.percentile(mask_ms, 90):.3f}",
            ],
            [
                "index gather (now)",
                f"{i:.3f}",
                f"{np.percentile(index_ms, 10):.3f}",
                f"{np.percentile(index_ms, 90):.3f}",
            ],
        ],
    )
    text = (
        f"{args.gaussians} isotropic Gaussians, {args.semantic} semantic channels, {100 * args.removed:g} % pruned, "
        f"after one Adam step; both ways alternating in one run.\n\n{table}\n\nRatio index/mask: **{i / m:.2f}**."
    )
    print(text)
    if not args.no_append:
        append_section("Pruning the mapping optimiser: index gather against mask indexing", text)


if __name__ == "__main__":
    main()
