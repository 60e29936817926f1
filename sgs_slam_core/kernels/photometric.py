"""The photometric term of the mapping loss, ``(1 - w) mean|x - y| + w (1 - SSIM(x, y))``, in PyTorch.

SSIM with "same" zero padding, an 11-tap Gaussian window and sigma 1.5, blurred by banded matrix
products (``band``, the faster form on the CPU) or separable depthwise convolutions (``conv``,
O(window) work per pixel, the faster form on CUDA). The compiled CPU kernels compute the same
function in ``kernels/cpu/photometric.cpp``.
"""

from __future__ import annotations

from typing import Literal

import torch
from torch import Tensor

from sgs_slam_core.metrics.image import blur_band, blur_conv, ssim

__all__ = ["SIGMA", "WINDOW", "SsimBlur", "photometric_loss"]

SsimBlur = Literal["band", "conv"]
WINDOW, SIGMA = 11, 1.5


def photometric_loss(
    pred: Tensor,  # [H, W, C] rendered, differentiable
    target: Tensor,  # [H, W, C] measured (no gradient)
    ignore: Tensor | None,  # [H, W] bool: pixels that count as matched (no error, no gradient)
    ssim_weight: float,
    blur: SsimBlur = "band",
) -> Tensor:  # []
    """``(1 - w) mean|pred - target| + w (1 - mean SSIM(pred, target))`` over every value."""
    if ignore is not None:
        target = torch.where(ignore[..., None], pred.detach(), target)
    loss = (pred - target).abs().mean()
    if ssim_weight > 0:
        window = blur_conv if blur == "conv" else blur_band
        loss = (1 - ssim_weight) * loss + ssim_weight * (1 - ssim(pred, target, WINDOW, SIGMA, "same", window))
    return loss
