"""Random Gaussian scenes for renderer tests, and frames rendered from them."""

from __future__ import annotations

import torch

from sgs_slam_core.frame_data import FrameTensors
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.geometry import Intrinsics
from sgs_slam_core.kernels import render
from sgs_slam_core.render import RenderSettings


def random_scene(
    n: int,
    width: int,
    height: int,
    seed: int = 0,
    dtype: torch.dtype = torch.float32,
    semantic: int = 3,
    anisotropic: bool = False,
    behind: int = 0,
) -> tuple[GaussianMap, Intrinsics]:
    """N Gaussians in a box 2-3.5 m in front of an identity camera; ``behind`` of them behind it."""
    g = torch.Generator().manual_seed(seed)
    lo = torch.tensor([-1.5, -1.1, 2.0], dtype=dtype)
    size = torch.tensor([3.0, 2.2, 1.5], dtype=dtype)
    means = torch.rand(n, 3, generator=g, dtype=dtype) * size + lo
    if behind:
        means[:behind, 2] = -means[:behind, 2]
    radius = 0.02 + 0.06 * torch.rand(n, 3 if anisotropic else 1, generator=g, dtype=dtype)
    quats = torch.nn.functional.normalize(torch.randn(n, 4, generator=g, dtype=dtype), dim=1) if anisotropic else None
    gm = GaussianMap(
        means=means,
        log_scales=radius.log(),
        logit_opacities=torch.randn(n, generator=g, dtype=dtype) * 1.5,
        colors=torch.rand(n, 3, generator=g, dtype=dtype),
        semantics=torch.rand(n, semantic, generator=g, dtype=dtype),
        labels=torch.zeros(n, dtype=torch.long),
        birth_frame=torch.zeros(n, dtype=torch.long),
        quats=quats,
    )
    k = Intrinsics(0.9 * width, 0.9 * width, (width - 1) / 2, (height - 1) / 2, width, height)
    return gm, k


def unexplained_frame(
    seed: int, ignore: bool, settings: RenderSettings, n: int = 600, width: int = 64, height: int = 48
) -> tuple[GaussianMap, FrameTensors]:
    """A random map and a frame it does not quite explain: its render from a moved camera, holes in the depth.

    ``ignore``: a fifth of the pixels are ignored (edit locks).
    """
    gm, k = random_scene(n, width, height, seed=seed)
    w2c = torch.eye(4)
    w2c[:3, 3] = torch.tensor([0.03, -0.02, 0.05])
    with torch.no_grad():
        target = render(gm, k, w2c, settings)
    g = torch.Generator().manual_seed(seed)
    depth = target.depth.clone()
    depth[torch.rand(depth.shape, generator=g) < 0.1] = 0  # no measurement
    mask = torch.rand(depth.shape, generator=g) < 0.2 if ignore else None
    return gm, FrameTensors(0, k, target.color, depth, None, target.semantic.softmax(-1), mask)
