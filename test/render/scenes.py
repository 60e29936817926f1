"""Random Gaussian scenes for renderer tests."""

from __future__ import annotations

import torch

from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.geometry import Intrinsics


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
