"""Dense all-pairs compositor: every pixel against every visible Gaussian.

A test reference for the tiled renderer only (cost is H * W * N); it shares no code with the tile
plan, so agreement checks the binning as well as the blending.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from sgs_slam_core.geometry.camera import pixel_grid
from sgs_slam_core.render.settings import RenderSettings

__all__ = ["composite_dense"]


def composite_dense(
    means2d: Tensor,  # [N, 2]
    conics: Tensor,  # [N, 3]
    opacities: Tensor,  # [N]
    features: Tensor,  # [N, D]
    depths: Tensor,  # [N]
    visible: Tensor,  # [N] bool
    width: int,
    height: int,
    settings: RenderSettings,
) -> tuple[Tensor, Tensor]:
    """Returns ``(image [H, W, D], silhouette [H, W])`` with plain autograd ops."""
    ids = torch.nonzero(visible).squeeze(1)
    ids = ids[torch.argsort(depths.detach()[ids], stable=True)]
    u, v = pixel_grid(height, width, means2d.device)
    px, py = u.reshape(-1, 1).to(means2d.dtype), v.reshape(-1, 1).to(means2d.dtype)  # [P, 1]
    mu, con, op, f = means2d[ids], conics[ids], opacities[ids], features[ids]
    dx, dy = px - mu[None, :, 0], py - mu[None, :, 1]  # [P, N']
    q = con[None, :, 0] * dx * dx + 2 * con[None, :, 1] * dx * dy + con[None, :, 2] * dy * dy
    raw = op[None, :] * torch.exp(-0.5 * q)
    keep = (q < settings.extent_sigma**2) & (raw > settings.alpha_min)
    alpha = torch.where(keep, raw.clamp_max(settings.alpha_max), torch.zeros_like(raw))
    log_floor = math.log(max(settings.min_transmittance, 1e-30))
    alpha = alpha * (torch.cumsum(torch.log1p(-alpha.detach()), dim=1) >= log_floor).to(alpha.dtype)
    log1m = torch.log1p(-alpha)
    csum = torch.cumsum(log1m, dim=1)
    w = alpha * torch.exp(csum - log1m)
    img = (w @ f).reshape(height, width, -1)
    sil = (w.sum(dim=1)).reshape(height, width)
    return img, sil
