"""``sgs-slam demo``: render a built-in semantic Gaussian scene from an orbit of cameras."""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import cv2
import numpy as np
import torch

from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.geometry import Intrinsics, se3_from_rt, se3_inverse
from sgs_slam_core.labels import LabelTable
from sgs_slam_core.render import RenderSettings, render
from sgs_slam_core.semantics import SemanticCodec, SemanticSettings


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the sub-command."""
    p = sub.add_parser("demo", help="render the built-in scene (CPU)")
    p.add_argument("--out", type=Path, default=Path("demo_out"), help="output folder (default: demo_out)")
    p.add_argument("--views", type=int, default=8)
    p.set_defaults(func=run)


def builtin_scene(per_object: int = 1500) -> tuple[GaussianMap, LabelTable]:
    """Four labelled objects (sphere, box, ring, floor) made of isotropic Gaussians."""
    table = LabelTable.nyu40()
    g = torch.Generator().manual_seed(0)
    parts, labels = [], []
    sphere = torch.nn.functional.normalize(torch.randn(per_object, 3, generator=g), dim=1) * 0.35
    parts.append(sphere + torch.tensor([-0.5, -0.1, 0.0]))
    labels.append(5)  # chair
    box = (torch.rand(per_object, 3, generator=g) - 0.5) * torch.tensor([0.5, 0.6, 0.5])
    parts.append(box + torch.tensor([0.5, 0.0, 0.0]))
    labels.append(7)  # table
    t = torch.rand(per_object, generator=g) * 2 * math.pi
    parts.append(torch.stack([0.3 * torch.cos(t), -0.7 + 0.0 * t, 0.3 * torch.sin(t)], 1))
    labels.append(35)  # lamp
    floor = (torch.rand(per_object * 2, 3, generator=g) - 0.5) * torch.tensor([2.4, 0.0, 2.4])
    parts.append(floor + torch.tensor([0.0, 0.35, 0.0]))
    labels.append(2)  # floor
    means = torch.cat(parts)
    label = torch.cat([torch.full((p.shape[0],), lab) for p, lab in zip(parts, labels, strict=True)])
    codec = SemanticCodec(SemanticSettings(), table)
    colors = codec.encode(label) * 0.8 + 0.2 * torch.rand(len(label), 3, generator=g)
    gm = GaussianMap(
        means=means,
        log_scales=torch.full((len(label), 1), math.log(0.025)),
        logit_opacities=torch.full((len(label),), 2.0),
        colors=colors,
        semantics=codec.encode(label),
        labels=label,
        birth_frame=torch.zeros(len(label), dtype=torch.long),
    )
    return gm, table


def orbit_c2w(angle: float, radius: float = 2.5, height: float = -0.8) -> torch.Tensor:  # [4, 4]
    """Camera on a circle around the origin looking at it (optical frame: y down)."""
    eye = torch.tensor([radius * math.sin(angle), height, -radius * math.cos(angle)])
    forward = torch.nn.functional.normalize(-eye, dim=0)
    right = torch.nn.functional.normalize(torch.linalg.cross(torch.tensor([0.0, 1.0, 0.0]), forward), dim=0)
    down = torch.linalg.cross(forward, right)
    return se3_from_rt(torch.stack([right, down, forward], dim=1), eye)


def run(args: argparse.Namespace) -> int:
    """Render the orbit and write colour | semantic | depth strips."""
    gm, table = builtin_scene()
    k = Intrinsics(200.0, 200.0, 159.5, 119.5, 320, 240)
    codec = SemanticCodec(SemanticSettings(), table)
    args.out.mkdir(parents=True, exist_ok=True)
    times = []
    for i in range(args.views):
        t0 = time.perf_counter()
        with torch.no_grad():
            out = render(gm, k, se3_inverse(orbit_c2w(2 * math.pi * i / args.views)), RenderSettings(backend="torch"))
        times.append(time.perf_counter() - t0)
        color = (out.color.clamp(0, 1).numpy() * 255).astype(np.uint8)
        semantic = table.colorize(out.labels(codec.decode).numpy() * (out.silhouette.numpy() > 0.5))
        depth = cv2.applyColorMap((out.depth.numpy() / 4.0 * 255).clip(0, 255).astype(np.uint8), cv2.COLORMAP_TURBO)
        strip = np.concatenate([color, semantic, depth[..., ::-1]], axis=1)
        cv2.imwrite(str(args.out / f"view_{i:02d}.png"), strip[..., ::-1])
    print(f"rendered {args.views} views of {len(gm):,} Gaussians at {k.width}x{k.height} to {args.out}/")
    print(f"median render time: {sorted(times)[len(times) // 2] * 1e3:.1f} ms per view (colour + depth + semantics)")
    return 0
