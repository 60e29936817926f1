"""How many Gaussians a render meets where the camera looked, tenth by tenth of a finished run.

A render's cost follows the Gaussians that may touch the image, so a map that keeps adding them where
the camera already looked makes each frame dearer as the run goes on. From a run folder of
``sgs-slam run`` (``map.sgsmap``, ``trajectory.txt``, ``frames.csv``), at ``--samples`` tracked
poses in each tenth of the run:

- the Gaussians in view then: those of the final map born by that frame (the map as it was, but
  for later optimisation and pruning), and the render time of that map;
- the same with the whole final map: what tracking those frames again would pay;
- the share of the final map's Gaussians in view whose centre lies more than 3 standard deviations
  behind the rendered surface, where it is opaque (silhouette > 0.9): layers that a render sorts
  but that no pixel shows.

    python bench/bench_view_density.py RUN_FOLDER [--samples 4]
"""

from __future__ import annotations

import argparse
import csv
import sys
import time
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import markdown_table
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.kernels.base import Kernels
from sgs_slam_core.kernels.factory import build_kernels
from sgs_slam_core.mapio.files import read_any_map
from sgs_slam_core.metrics.trajectory_io import read_tum_trajectory
from sgs_slam_core.render.output import RenderOutput
from sgs_slam_core.render.projection import frustum_candidates
from sgs_slam_core.render.settings import RenderSettings

TENTHS = 10
HIDDEN_SIGMAS = 3.0  # a centre this many standard deviations behind the rendered surface is hidden
OPAQUE = 0.9  # ... where the rendered silhouette is above this
RENDER_REPEATS = 5  # the fastest of this many renders is the render time


@dataclass(frozen=True)
class ViewDensity:
    """One pose: Gaussians in view of the map then and now, hidden share now, render times (ms)."""

    then: float  # a count, or a mean of counts
    then_ms: float
    now: float
    now_ms: float
    hidden: float  # share of ``now`` centred behind the opaque rendered surface


def born_by(g: GaussianMap, frame: int) -> GaussianMap:
    """The Gaussians of ``g`` added at or before ``frame``."""
    return g.select(g.birth_frame <= frame)


def rendered(
    kernels: Kernels, g: GaussianMap, k: Intrinsics, w2c: torch.Tensor
) -> tuple[float, RenderOutput]:  # w2c [4, 4]
    """The fastest of ``RENDER_REPEATS`` renders (ms), and the rendering."""
    times = []
    for _ in range(RENDER_REPEATS):
        t0 = time.perf_counter()
        out = kernels.render(g, k, w2c, with_semantics=False)
        times.append(time.perf_counter() - t0)
    return 1e3 * min(times), out


def hidden_share(
    g: GaussianMap, k: Intrinsics, w2c: torch.Tensor, ids: torch.Tensor, out: RenderOutput
) -> float:  # ids [M]
    """The share of ``ids`` whose centre is behind the opaque surface of ``out`` by ``HIDDEN_SIGMAS``."""
    surface = out.depth / out.silhouette.clamp_min(1e-6)  # [H, W] m
    cam = g.means[ids] @ w2c[:3, :3].T + w2c[:3, 3]  # [M, 3]
    u = torch.round(k.fx * cam[:, 0] / cam[:, 2] + k.cx).long()
    v = torch.round(k.fy * cam[:, 1] / cam[:, 2] + k.cy).long()
    inside = (u >= 0) & (u < k.width) & (v >= 0) & (v < k.height)
    u, v, z = u[inside], v[inside], cam[inside, 2]
    sigma = g.log_scales[ids][inside].exp().amax(dim=-1)
    hidden = (z > surface[v, u] + HIDDEN_SIGMAS * sigma) & (out.silhouette[v, u] > OPAQUE)
    return float(hidden.sum()) / max(len(ids), 1)


def density(kernels: Kernels, g: GaussianMap, k: Intrinsics, c2w: np.ndarray, frame: int) -> ViewDensity:  # c2w [4, 4]
    """Tracked frame ``frame``'s view from ``c2w``, rendered by ``kernels`` (built once by the caller)."""
    w2c = torch.as_tensor(np.linalg.inv(c2w), dtype=torch.float32, device=g.device)
    then = born_by(g, frame)
    then_ids = frustum_candidates(then.means, then.log_scales, w2c, k, RenderSettings())
    now_ids = frustum_candidates(g.means, g.log_scales, w2c, k, RenderSettings())
    then_ms, _ = rendered(kernels, then, k, w2c)
    now_ms, out = rendered(kernels, g, k, w2c)
    return ViewDensity(len(then_ids), then_ms, len(now_ids), now_ms, hidden_share(g, k, w2c, now_ids, out))


def mean_of(views: list[ViewDensity]) -> ViewDensity:
    """The field-by-field mean of ``views``."""
    return ViewDensity(*(float(np.mean([getattr(v, f.name) for v in views])) for f in fields(ViewDensity)))


def tracked_frames(run: Path) -> tuple[list[int], np.ndarray]:  # [N] frame indices, [N, 4, 4] c2w
    """The tracked frames' indices (as ``birth_frame`` counts them) and poses, in order."""
    stamps, c2w = read_tum_trajectory(run / "trajectory.txt")
    pose_at = dict(zip(stamps.tolist(), c2w, strict=True))
    with (run / "frames.csv").open() as f:
        rows = [r for r in csv.DictReader(f) if r["tracking_state"] != "lost" and int(r["stamp_ns"]) in pose_at]
    return [int(r["frame"]) for r in rows], np.stack([pose_at[int(r["stamp_ns"])] for r in rows])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("run", type=Path, help="an sgs-slam run folder")
    parser.add_argument("--samples", type=int, default=4, help="poses per tenth")
    args = parser.parse_args()
    saved = read_any_map(args.run / "map.sgsmap")
    frames, c2w = tracked_frames(args.run)
    kernels = build_kernels(RenderSettings(), saved.gaussians.device)
    rows = []
    for tenth in range(TENTHS):
        lo, hi = tenth * len(frames) // TENTHS, (tenth + 1) * len(frames) // TENTHS
        picks = np.linspace(lo, hi - 1, args.samples).round().astype(int)
        m = mean_of([density(kernels, saved.gaussians, saved.intrinsics, c2w[i], frames[i]) for i in picks])
        rows.append([f"{10 * tenth}-{10 * (tenth + 1)} %", f"{m.then:,.0f}", f"{m.then_ms:.2f}", f"{m.now:,.0f}",
                     f"{m.now_ms:.2f}", f"{100 * m.hidden:.0f} %"])  # fmt: skip
    headers = ["tenth", "in view then", "render ms then", "in view, final map", "render ms", "hidden (final map)"]
    print(markdown_table(headers, rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
