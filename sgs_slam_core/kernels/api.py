"""``render()``: colour, depth, silhouette and semantic channels of a Gaussian map in one pass.

A convenience over :func:`sgs_slam_core.kernels.build_kernels`: the SLAM builds its kernels once and
calls their ``render``. The reference and gsplat backends move the Gaussians into the camera frame in
PyTorch, so the gradients with respect to ``w2c`` come from autograd there; the compiled CPU backend
computes them in C++ for isotropic maps.
"""

from __future__ import annotations

from torch import Tensor

from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.kernels.factory import build_kernels
from sgs_slam_core.render.output import RenderOutput
from sgs_slam_core.render.settings import RenderSettings

__all__ = ["render"]


def render(
    gaussians: GaussianMap,
    intrinsics: Intrinsics,
    w2c: Tensor,  # [4, 4] world-to-camera, may require grad
    settings: RenderSettings | None = None,
    with_semantics: bool = True,
) -> RenderOutput:
    """Render every channel of ``gaussians`` seen from ``w2c`` in one pass.

    With ``with_semantics=False`` the semantic channels are skipped (``semantic`` is then ``[H, W, 0]``).
    """
    kernels = build_kernels(settings or RenderSettings(), gaussians.device)
    return kernels.render(gaussians, intrinsics, w2c, with_semantics)
