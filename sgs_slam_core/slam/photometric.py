"""The photometric term of the mapping loss, ``(1 - w) mean|x - y| + w (1 - SSIM(x, y))``, per device.

Three implementations of the same function ("same" zero padding, 11-tap Gaussian window, sigma 1.5):

- ``fused`` (CPU): one C++ call computes the loss and its gradient (``slam/cpu/photometric.cpp``,
  built on first use). Measured at 160x120 x 3 channels, loss and gradient, 2 cores: about 10x the
  reference (BENCHMARKS.md).
- ``conv``: SSIM with separable depthwise convolutions, O(window) work per pixel (CUDA's choice).
- ``reference``: :func:`sgs_slam_core.metrics.image.ssim` with banded matrix products, the fastest
  pure-PyTorch form on the CPU; used there when the extension cannot be built.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import torch
from torch import Tensor

from sgs_slam_core.metrics.image import blur_band, blur_conv, ssim
from sgs_slam_core.native import NativeExtension

__all__ = ["EXTENSION", "PhotometricBackend", "photometric_loss", "resolve_photometric_backend"]

PhotometricBackend = Literal["auto", "fused", "conv", "reference"]
EXTENSION = NativeExtension("photometric", Path(__file__).with_name("cpu") / "photometric.cpp", "the fused SSIM loss")
WINDOW, SIGMA = 11, 1.5


def resolve_photometric_backend(requested: PhotometricBackend, device: torch.device) -> str:
    """``auto``: ``fused`` on the CPU when it builds, ``conv`` on other devices, else ``reference``."""
    if requested != "auto":
        return requested
    if device.type == "cpu":
        return "fused" if EXTENSION.is_available() else "reference"
    return "conv"


def photometric_loss(
    pred: Tensor,  # [H, W, C] rendered, differentiable
    target: Tensor,  # [H, W, C] measured (no gradient)
    ignore: Tensor | None,  # [H, W] bool: pixels that count as matched (no error, no gradient)
    ssim_weight: float,
    backend: PhotometricBackend = "auto",
) -> Tensor:  # []
    """``(1 - w) mean|pred - target| + w (1 - mean SSIM(pred, target))`` over every value."""
    if ignore is not None:
        target = torch.where(ignore[..., None], pred.detach(), target)
    name = resolve_photometric_backend(backend, pred.device)
    if name == "fused":
        return _FusedPhotometric.apply(pred, target.detach(), ssim_weight)
    loss = (pred - target).abs().mean()
    if ssim_weight > 0:
        blur = blur_conv if name == "conv" else blur_band
        loss = (1 - ssim_weight) * loss + ssim_weight * (1 - ssim(pred, target, WINDOW, SIGMA, "same", blur))
    return loss


class _FusedPhotometric(torch.autograd.Function):
    @staticmethod
    def forward(ctx: Any, pred: Tensor, target: Tensor, ssim_weight: float) -> Tensor:  # type: ignore[override]
        need_grad = pred.requires_grad
        loss, grad = EXTENSION.module().photometric_loss(
            pred.detach(), target, float(ssim_weight), WINDOW, SIGMA, need_grad, torch.get_num_threads()
        )
        ctx.save_for_backward(grad if need_grad else None)
        return loss

    @staticmethod
    def backward(ctx: Any, grad_out: Tensor) -> tuple[Tensor | None, None, None]:  # type: ignore[override]
        (grad,) = ctx.saved_tensors
        return (grad * grad_out if grad is not None else None), None, None
