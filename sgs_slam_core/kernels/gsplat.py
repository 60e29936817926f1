"""The CUDA kernels: gsplat renders (one ``gsplat.rasterization`` call for colour, semantics and depth).

The losses are the PyTorch reference's with the convolutional SSIM window. gsplat is imported
lazily and only for CUDA tensors: on a CPU machine with ``nvcc`` on the PATH any gsplat CUDA op
would start a JIT build that fails.

Differences from the torch backend, by design of gsplat 1.5: alpha is clamped to 0.999 (ours 0.99),
footprints use gsplat's own radius rule, and its pixel centres sit at +0.5 (we shift cx, cy).
"""

from __future__ import annotations

import functools
import importlib
from types import ModuleType
from typing import TYPE_CHECKING

import torch
from torch import Tensor

from sgs_slam_core.errors import BackendUnavailableError
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.kernels.reference import ReferenceKernels
from sgs_slam_core.render.output import CameraGaussians, RenderOutput, to_camera
from sgs_slam_core.render.settings import RenderSettings

if TYPE_CHECKING:
    from sgs_slam_core.gaussians import GaussianMap

__all__ = ["GsplatKernels", "import_error", "is_available", "padded_channels", "rasterize"]

# Channel counts (features + depth) with a compiled kernel in gsplat 1.5 (csrc/Rasterization.cpp).
_KERNEL_CHANNELS = (1, 2, 3, 4, 5, 8, 9, 16, 17, 32, 33, 64, 65, 128, 129, 256, 257, 512, 513)


@functools.cache
def _load() -> ModuleType | Exception:
    try:
        return importlib.import_module("gsplat")
    except Exception as err:
        return err


def is_available() -> bool:
    """True when ``import gsplat`` works (it does not compile anything)."""
    return isinstance(_load(), ModuleType)


def import_error() -> str:
    """Why gsplat is unavailable, or an empty string."""
    mod = _load()
    return "" if isinstance(mod, ModuleType) else f"{type(mod).__name__}: {mod}"


def padded_channels(num_features: int) -> int:
    """Feature width to pass so that features + depth hit a compiled kernel size."""
    for total in _KERNEL_CHANNELS:
        if total >= num_features + 1:
            return total - 1
    raise ValueError(f"{num_features} channels exceed gsplat's largest single-pass kernel (512)")


def rasterize(cam: CameraGaussians, intrinsics: Intrinsics, settings: RenderSettings) -> tuple[Tensor, Tensor, Tensor]:
    """Returns ``(features [H, W, D], depth [H, W], silhouette [H, W])`` for camera-frame Gaussians."""
    mod = _load()
    if not isinstance(mod, ModuleType):
        raise BackendUnavailableError(f"gsplat unavailable: {import_error()}")
    n, d = cam.features.shape
    width = padded_channels(d)
    feats = cam.features if width == d else torch.cat([cam.features, cam.features.new_zeros(n, width - d)], 1)
    if cam.quats is None:
        scales = cam.scales[:, None].expand(n, 3)
        quats = cam.features.new_tensor([1.0, 0.0, 0.0, 0.0]).expand(n, 4)
    else:
        scales, quats = cam.scales, cam.quats
    k = cam.means.new_tensor(
        [[intrinsics.fx, 0.0, intrinsics.cx + 0.5], [0.0, intrinsics.fy, intrinsics.cy + 0.5], [0.0, 0.0, 1.0]]
    )
    colors, alphas, _ = mod.rasterization(
        means=cam.means,
        quats=quats,
        scales=scales,
        opacities=cam.opacities,
        colors=feats,
        viewmats=torch.eye(4, device=cam.means.device, dtype=cam.means.dtype)[None],
        Ks=k[None],
        width=intrinsics.width,
        height=intrinsics.height,
        near_plane=settings.near_plane,
        eps2d=settings.eps2d,
        sh_degree=None,
        packed=False,
        render_mode="RGB+D",
        channel_chunk=width + 1,
    )
    out = colors[0]
    return out[..., :d], out[..., -1], alphas[0, ..., 0]


class GsplatKernels(ReferenceKernels):
    """gsplat's rasteriser for CUDA tensors; the losses and Gauss-Newton steps of the reference."""

    name = "gsplat"

    def __init__(self, settings: RenderSettings, device: torch.device) -> None:
        super().__init__(settings, device, ssim_blur="conv")

    def _render(
        self, gaussians: GaussianMap, intrinsics: Intrinsics, w2c: Tensor, with_semantics: bool
    ) -> RenderOutput:
        feats, depth, sil = rasterize(to_camera(gaussians, w2c, with_semantics), intrinsics, self.settings)
        return RenderOutput(
            color=feats[..., :3], depth=depth, silhouette=sil, semantic=feats[..., 3:], backend=self.name
        )
