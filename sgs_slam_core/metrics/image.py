"""Image metrics on ``[H, W, C]`` tensors in [0, 1]: PSNR, SSIM, MS-SSIM, depth L1.

:func:`ssim` is differentiable and also serves as the mapping loss's SSIM term (with
``padding="same"``, as 3DGS/SplaTAM); as a metric it uses the standard "valid" window
(scikit-image / pytorch_msssim convention).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from typing import Literal

import torch
import torch.nn.functional as nn_f
from torch import Tensor

from sgs_slam_core.errors import ShapeError

__all__ = ["MS_SSIM_WEIGHTS", "blur_band", "blur_conv", "depth_l1", "gaussian_window", "ms_ssim", "psnr", "ssim"]

MS_SSIM_WEIGHTS = (0.0448, 0.2856, 0.3001, 0.2363, 0.1333)
_C1, _C2 = 0.01**2, 0.03**2


def _check_pair(pred: Tensor, gt: Tensor) -> None:
    if pred.shape != gt.shape:
        raise ShapeError(f"prediction {tuple(pred.shape)} and ground truth {tuple(gt.shape)} differ")
    if pred.ndim != 3:
        raise ShapeError(f"images must be [H, W, C], got {tuple(pred.shape)}")


def psnr(pred: Tensor, gt: Tensor, mask: Tensor | None = None) -> float:
    """PSNR (dB, data range 1). With ``mask [H, W]`` the MSE is taken over the masked pixels only."""
    _check_pair(pred, gt)
    err = (pred.detach().float() - gt.float()) ** 2
    if mask is not None:
        if mask.shape != pred.shape[:2]:
            raise ShapeError(f"mask {tuple(mask.shape)} does not match image {tuple(pred.shape[:2])}")
        if not bool(mask.any()):
            return float("nan")
        mse = err[mask.bool()].mean()
    else:
        mse = err.mean()
    return float("inf") if mse.item() == 0 else float(-10 * torch.log10(mse))


def gaussian_window(size: int, sigma: float, like: Tensor) -> Tensor:  # [size] normalised 1D taps
    """The SSIM window's 1D taps (dtype and device of ``like``)."""
    x = torch.arange(size, dtype=like.dtype, device=like.device) - (size - 1) / 2
    g = torch.exp(-(x**2) / (2 * sigma**2))
    return g / g.sum()


def _band(n: int, size: int, sigma: float, pad: int, dtype: torch.dtype, device: torch.device) -> Tensor:
    """[n_out, n] matrix applying the 1D window along an axis; zero padding by ``pad`` (0 = valid).

    Made once per shape, dtype and device; while ``torch.compile`` traces, a fresh one (the compiled
    graph holds it as a constant).
    """
    if torch.compiler.is_compiling():
        return _band_matrix(n, size, sigma, pad, dtype, device)
    return _cached_band(n, size, sigma, pad, dtype, device)


def _band_matrix(n: int, size: int, sigma: float, pad: int, dtype: torch.dtype, device: torch.device) -> Tensor:
    taps = gaussian_window(size, sigma, torch.empty(0, dtype=dtype, device=device))
    n_out = n + 2 * pad - size + 1
    offset = torch.arange(n, device=device)[None, :] - torch.arange(n_out, device=device)[:, None] + pad
    inside = (offset >= 0) & (offset < size)
    return torch.where(inside, taps[offset.clamp(0, size - 1)], torch.zeros((), dtype=dtype, device=device))


_cached_band = functools.lru_cache(maxsize=32)(_band_matrix)


def blur_band(x: Tensor, size: int, sigma: float, pad: int) -> Tensor:  # [1, C, H, W] -> [1, C, H', W']
    """Separable Gaussian filter as two banded matrix products (zero padding by ``pad``; the reference).

    O(H + W) work per pixel, but the fastest pure-PyTorch form on the CPU (measured against
    :func:`blur_conv`).
    """
    h, w = x.shape[-2:]
    rows = _band(h, size, sigma, pad, x.dtype, x.device)
    cols = _band(w, size, sigma, pad, x.dtype, x.device)
    return rows @ x @ cols.T


def blur_conv(x: Tensor, size: int, sigma: float, pad: int) -> Tensor:  # [1, C, H, W] -> [1, C, H', W']
    """The same filter as two depthwise convolutions: O(size) work per pixel (the GPU's choice)."""
    c = x.shape[1]
    taps = gaussian_window(size, sigma, x)
    x = nn_f.conv2d(x, taps.view(1, 1, size, 1).expand(c, 1, size, 1), padding=(pad, 0), groups=c)
    return nn_f.conv2d(x, taps.view(1, 1, 1, size).expand(c, 1, 1, size), padding=(0, pad), groups=c)


Blur = Callable[[Tensor, int, float, int], Tensor]


def _ssim_maps(
    x: Tensor, y: Tensor, size: int, sigma: float, pad: int, blur: Blur = blur_band
) -> tuple[Tensor, Tensor]:
    c = x.shape[1]
    moments = blur(torch.cat([x, y, x * x, y * y, x * y], dim=1), size, sigma, pad)  # all five in one pass
    mu_x, mu_y, exx, eyy, exy = moments.split(c, dim=1)
    sxx = exx - mu_x**2
    syy = eyy - mu_y**2
    sxy = exy - mu_x * mu_y
    cs = (2 * sxy + _C2) / (sxx + syy + _C2)
    lum = (2 * mu_x * mu_y + _C1) / (mu_x**2 + mu_y**2 + _C1)
    return lum * cs, cs  # [1, C, H', W'] each


def ssim(
    pred: Tensor,  # [H, W, C]
    gt: Tensor,  # [H, W, C]
    window: int = 11,
    sigma: float = 1.5,
    padding: Literal["valid", "same"] = "valid",
    blur: Blur = blur_band,
) -> Tensor:
    """Mean single-scale SSIM (Gaussian window, C1 = 0.01^2, C2 = 0.03^2); differentiable.

    ``blur``: :func:`blur_band` (the reference, fastest in PyTorch on the CPU) or :func:`blur_conv`.
    """
    _check_pair(pred, gt)
    if padding == "valid" and min(pred.shape[:2]) < window:
        raise ShapeError(f"image {tuple(pred.shape[:2])} is smaller than the {window}px SSIM window")
    x, y = pred.permute(2, 0, 1)[None], gt.permute(2, 0, 1)[None]
    ssim_map, _ = _ssim_maps(x, y, window, sigma, window // 2 if padding == "same" else 0, blur)
    return ssim_map.mean()


def ms_ssim(pred: Tensor, gt: Tensor, window: int = 11, sigma: float = 1.5) -> float:
    """Multi-scale SSIM (Wang et al. 2003; pytorch_msssim's definition, which SplaTAM reports as "SSIM").

    Uses the standard five scales when the shorter side exceeds 160 px; smaller images use as many
    scales as fit, with the weights renormalised (documented deviation).
    """
    _check_pair(pred, gt)
    short = min(pred.shape[:2])
    if short < window:
        raise ShapeError(f"image {tuple(pred.shape[:2])} is smaller than the {window}px SSIM window")
    levels = min(5, 1 + math.floor(math.log2(short / window)))  # each level halves the image
    weights = torch.tensor(MS_SSIM_WEIGHTS[:levels], dtype=torch.float64, device=pred.device)
    weights = weights / weights.sum()
    x, y = pred.detach().float().permute(2, 0, 1)[None], gt.float().permute(2, 0, 1)[None]
    values = []
    for level in range(levels):
        ssim_map, cs = _ssim_maps(x, y, window, sigma, 0)
        values.append((ssim_map if level == levels - 1 else cs).mean(dim=(2, 3)).clamp_min(0).mean())
        if level < levels - 1:
            x, y = nn_f.avg_pool2d(x, 2), nn_f.avg_pool2d(y, 2)
    return float(torch.prod(torch.stack(values).double() ** weights))


def depth_l1(pred: Tensor, gt: Tensor) -> float:
    """Mean |pred - gt| (m) over pixels with ground-truth depth > 0."""
    if pred.shape != gt.shape or pred.ndim != 2:
        raise ShapeError(f"depth maps must both be [H, W], got {tuple(pred.shape)} and {tuple(gt.shape)}")
    valid = gt > 0
    if not bool(valid.any()):
        return float("nan")
    return float((pred.detach()[valid] - gt[valid]).abs().mean())
