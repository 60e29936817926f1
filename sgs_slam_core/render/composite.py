"""Front-to-back alpha compositing of 2D Gaussians over a tile plan.

Two implementations of the same maths:

* :func:`composite` - a ``torch.autograd.Function`` with a hand-written backward that recomputes
  per-pair quantities chunk by chunk instead of storing them (the fast CPU path, ~3x less memory
  traffic than autograd);
* :func:`composite_autograd` - the identical forward written with ordinary differentiable ops,
  the reference the custom backward is tested against.

Per pixel p and Gaussian i (depth order): q = A dx^2 + 2B dx dy + C dy^2 with dx = p_x - u_i;
alpha_i = min(alpha_max, o_i exp(-q/2)), zeroed unless q < extent^2 and o_i exp(-q/2) > alpha_min;
a pixel is "done" at the first Gaussian that would take its transmittance below
max(min_transmittance, 1e-30): that Gaussian and all later ones get alpha 0 (3DGS's early stop);
T_i = prod_{j<i} (1 - alpha_j); w_i = alpha_i T_i; out = sum_i w_i f_i; silhouette = sum_i w_i.
"""

from __future__ import annotations

import math
from typing import Any

import torch
import torch.nn.functional as nn_f
from torch import Tensor

from sgs_slam_core.render.settings import RenderSettings
from sgs_slam_core.render.tiling import TileChunk, TilePlan

__all__ = ["composite", "composite_autograd"]

_PAD_MEAN = -1.0e6  # the pad Gaussian sits far off-image: alpha 0 everywhere
_LOG_T_FLOOR = -80.0


def _pad(means2d: Tensor, conics: Tensor, opacities: Tensor, features: Tensor) -> tuple[Tensor, ...]:
    """Append the transparent pad Gaussian (index N) to every per-Gaussian tensor."""
    m = torch.cat([means2d, means2d.new_full((1, 2), _PAD_MEAN)])
    c = torch.cat([conics, conics.new_tensor([[1.0, 0.0, 1.0]])])
    o = torch.cat([opacities, opacities.new_zeros(1)])
    f = torch.cat([features, features.new_zeros(1, features.shape[1])])
    return m, c, o, f


def _pair_terms(chunk: TileChunk, m: Tensor, c: Tensor, o: Tensor, s: RenderSettings) -> Tensor:
    """Clamped alpha ``[Tc, P, K]`` per pixel and slot, with plain differentiable ops (reference)."""
    g = chunk.gauss
    mu, con, op = m[g], c[g], o[g]  # [Tc, K, 2], [Tc, K, 3], [Tc, K]
    dx = chunk.px[:, :, None] - mu[:, None, :, 0]  # [Tc, P, K]
    dy = chunk.py[:, :, None] - mu[:, None, :, 1]
    q = con[:, None, :, 0] * dx * dx + 2 * con[:, None, :, 1] * dx * dy + con[:, None, :, 2] * dy * dy
    raw = op[:, None, :] * torch.exp(-0.5 * q)
    keep = (q < s.extent_sigma**2) & (raw > s.alpha_min)
    alpha = torch.where(keep, raw.clamp_max(s.alpha_max), torch.zeros_like(raw))
    return alpha * _not_done(alpha.detach(), s)


def _not_done(alpha: Tensor, s: RenderSettings) -> Tensor:  # [Tc, P, K] 1 = blended, 0 = after the early stop
    """1 for slots blended before the pixel's transmittance would drop below the threshold, else 0.

    The inclusive transmittance of the unmasked alphas is monotone, so the kept slots are a prefix.
    """
    log_floor = math.log(max(s.min_transmittance, 1e-30))
    return (torch.cumsum(torch.log1p(-alpha), dim=2) >= log_floor).to(alpha.dtype)


def _local_offsets(chunk: TileChunk, m: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Slot means relative to the tile origin ``[Tc, K]`` and offsets ``[Tc, ts, K]`` per column / row."""
    ts = round(chunk.px.shape[1] ** 0.5)
    mu = m[chunk.gauss]
    ul = mu[..., 0] - chunk.x0[:, None]
    vl = mu[..., 1] - chunk.y0[:, None]
    lin = torch.arange(ts, dtype=m.dtype, device=m.device)[None, :, None]
    return ul, vl, lin - ul[:, None, :], lin - vl[:, None, :]


def _alpha_fast(chunk: TileChunk, m: Tensor, c: Tensor, o: Tensor, s: RenderSettings) -> Tensor:
    """Same values as :func:`_pair_terms`, without autograd and with few full-size passes.

    The quadratic form is separable per tile column (dx) and row (dy) except for the cross term,
    so only three operations touch every pixel x slot element before the exponential.
    """
    _, _, dxs, dys = _local_offsets(chunk, m)  # [Tc, ts, K]
    con = c[chunk.gauss]
    a, b, cc = con[..., 0:1].transpose(1, 2), con[..., 1:2].transpose(1, 2), con[..., 2:3].transpose(1, 2)
    tc, ts, k = dxs.shape
    q = (2 * b * dxs)[:, None, :, :] * dys[:, :, None, :]  # [Tc, ts_y, ts_x, K]
    q += (a * dxs * dxs)[:, None, :, :]
    q += (cc * dys * dys)[:, :, None, :]
    # Only float arithmetic from here on: bool masks, masked_fill and exp(-inf) are slow paths on
    # CPU, and exp of a large argument would produce slow denormals. Clamping q just above the
    # cut-off keeps exp normal; the thresholds then zero everything outside the footprint.
    e2 = s.extent_sigma**2
    falloff = q.reshape(tc, ts * ts, k).clamp_max_(e2 + 1.0).mul_(-0.5).exp_()
    nn_f.threshold_(falloff, math.exp(-0.5 * e2), 0.0)  # q < extent^2
    alpha = nn_f.threshold_(falloff.mul_(o[chunk.gauss][:, None, :]), s.alpha_min, 0.0)
    alpha.clamp_max_(s.alpha_max)
    return alpha.mul_(_not_done(alpha, s))


def _weights(alpha: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Exclusive transmittance, weights and final transmittance along the slot axis (dim 2)."""
    log1m = torch.log1p(-alpha)
    csum = torch.cumsum(log1m, dim=2)
    trans = torch.exp(csum - log1m)
    return trans, alpha * trans, torch.exp(csum[:, :, -1])


def _weights_fast(alpha: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """:func:`_weights` with in-place arithmetic (no autograd).

    log T is floored at -80 (T < 2e-35) so exp never produces denormals; such slots carry no weight.
    """
    log1m = alpha.neg().log1p_()
    csum = torch.cumsum(log1m, dim=2).clamp_min_(_LOG_T_FLOOR)
    t_final = csum[:, :, -1].exp()
    trans = csum.sub_(log1m).exp_()
    return trans, alpha * trans, t_final


def _moment_basis(ts: int, dtype: torch.dtype, device: torch.device) -> Tensor:  # [6, P]
    """Per tile pixel (1, x, y, x^2, x y, y^2) in tile-local coordinates."""
    lin = torch.arange(ts, dtype=dtype, device=device)
    x, y = lin.repeat(ts), lin.repeat_interleave(ts)
    return torch.stack([torch.ones_like(x), x, y, x * x, x * y, y * y])


def _to_image(tiles_img: Tensor, plan: TilePlan) -> Tensor:  # [T, P, D] -> [H, W, D]
    ts = plan.tile_size
    d = tiles_img.shape[-1]
    img = tiles_img.reshape(plan.tiles_y, plan.tiles_x, ts, ts, d).permute(0, 2, 1, 3, 4)
    return img.reshape(plan.tiles_y * ts, plan.tiles_x * ts, d)[: plan.height, : plan.width]


def _to_tiles(img: Tensor, plan: TilePlan) -> Tensor:  # [H, W, D] -> [T, P, D]
    ts = plan.tile_size
    d = img.shape[-1]
    full = img.new_zeros(plan.tiles_y * ts, plan.tiles_x * ts, d)
    full[: plan.height, : plan.width] = img
    return full.reshape(plan.tiles_y, ts, plan.tiles_x, ts, d).permute(0, 2, 1, 3, 4).reshape(-1, ts * ts, d)


class _Composite(torch.autograd.Function):
    @staticmethod
    def forward(  # type: ignore[override]
        ctx: Any,
        means2d: Tensor,  # [N, 2]
        conics: Tensor,  # [N, 3]
        opacities: Tensor,  # [N]
        features: Tensor,  # [N, D]
        plan: TilePlan,
        settings: RenderSettings,
    ) -> tuple[Tensor, Tensor]:
        m, c, o, f = _pad(means2d, conics, opacities, features)
        d = features.shape[1]
        out = features.new_zeros(plan.num_tiles, plan.tile_size**2, d + 1)  # last channel: silhouette
        for chunk in plan.chunks:
            _, w, t_final = _weights_fast(_alpha_fast(chunk, m, c, o, settings))
            out[chunk.tiles, :, :d] = torch.bmm(w, f[chunk.gauss])
            out[chunk.tiles, :, d] = 1 - t_final
        ctx.save_for_backward(m, c, o, f)
        ctx.plan, ctx.settings = plan, settings
        img = _to_image(out, plan)
        return img[..., :d], img[..., d]

    @staticmethod
    def backward(ctx: Any, grad_img: Tensor, grad_sil: Tensor) -> tuple[Tensor | None, ...]:  # type: ignore[override]
        m, c, o, f = ctx.saved_tensors
        plan: TilePlan = ctx.plan
        s: RenderSettings = ctx.settings
        grads_tiles = _to_tiles(torch.cat([grad_img, grad_sil[..., None]], dim=-1), plan)
        d = f.shape[1]
        g_geom = m.new_zeros(m.shape[0], 6)  # (u, v, A, B, C, opacity)
        g_f = torch.zeros_like(f)
        basis = _moment_basis(plan.tile_size, m.dtype, m.device)
        for chunk in plan.chunks:
            alpha = _alpha_fast(chunk, m, c, o, s)
            trans, w, _ = _weights_fast(alpha)
            gt = grads_tiles[chunk.tiles]  # [Tc, P, D + 1]
            idx = chunk.gauss.reshape(-1)
            g_f.index_add_(0, idx, torch.bmm(w.transpose(1, 2), gt[:, :, :d]).reshape(-1, d))
            # dL/dalpha_i = T_i c_i - (sum_{j>i} w_j c_j) / (1 - alpha_i), c_i = g . f_i + g_sil.
            ci = torch.baddbmm(gt[:, :, d : d + 1], gt[:, :, :d], f[chunk.gauss].transpose(1, 2))
            wc = torch.cumsum(w.mul_(ci), dim=2)
            suffix = torch.sub(wc[:, :, -1:], wc).div_(torch.rsub(alpha, 1.0))
            g_alpha = trans.mul_(ci).sub_(suffix)
            # alpha = o exp(-q/2) where neither clamped nor cut: dalpha/dq = -alpha/2, dalpha/do = alpha/o.
            # neg_free = -alpha where alpha < alpha_max, else 0 (clamped alphas pass no gradient).
            neg_free = nn_f.threshold_(alpha.neg_(), -s.alpha_max, 0.0)
            mom = torch.matmul(basis, g_alpha.mul_(neg_free))  # [Tc, 6, K]: -sum_p g_alpha alpha (1, x, y, ...)
            g_geom.index_add_(0, idx, _geometry_grads(chunk, m, c, o, mom).reshape(-1, 6))
        n = plan.num_gaussians
        return g_geom[:n, 0:2], g_geom[:n, 2:5], g_geom[:n, 5], g_f[:n], None, None


def _geometry_grads(chunk: TileChunk, m: Tensor, c: Tensor, o: Tensor, mom: Tensor) -> Tensor:  # [Tc, K, 6]
    """Per-slot gradients (u, v, A, B, C, opacity) from pixel moments of g_alpha * alpha."""
    ul, vl, _, _ = _local_offsets(chunk, m)
    m0, mx, my, mxx, mxy, myy = (0.5 * mom).unbind(1)  # moments of dL/dq = -g_alpha alpha / 2
    s_x, s_y = mx - ul * m0, my - vl * m0  # sum dL/dq * dx, * dy
    s_xx = mxx - 2 * ul * mx + ul * ul * m0
    s_xy = mxy - ul * my - vl * mx + ul * vl * m0
    s_yy = myy - 2 * vl * my + vl * vl * m0
    a, b, cc = c[chunk.gauss].unbind(-1)
    g_u = -2 * (a * s_x + b * s_y)
    g_v = -2 * (b * s_x + cc * s_y)
    g_o = -mom[:, 0] / o[chunk.gauss].clamp_min(1e-30)
    return torch.stack([g_u, g_v, s_xx, 2 * s_xy, s_yy, g_o], dim=-1)


def composite(
    means2d: Tensor,  # [N, 2]
    conics: Tensor,  # [N, 3]
    opacities: Tensor,  # [N]
    features: Tensor,  # [N, D]
    plan: TilePlan,
    settings: RenderSettings,
) -> tuple[Tensor, Tensor]:
    """Blend ``features`` front to back: returns ``(image [H, W, D], silhouette [H, W])``."""
    return _Composite.apply(means2d, conics, opacities, features, plan, settings)


def composite_autograd(
    means2d: Tensor,  # [N, 2]
    conics: Tensor,  # [N, 3]
    opacities: Tensor,  # [N]
    features: Tensor,  # [N, D]
    plan: TilePlan,
    settings: RenderSettings,
) -> tuple[Tensor, Tensor]:
    """Reference for :func:`composite`: same forward, gradients by autograd."""
    m, c, o, f = _pad(means2d, conics, opacities, features)
    d = features.shape[1]
    rows = []
    for chunk in plan.chunks:
        _, w, t_final = _weights(_pair_terms(chunk, m, c, o, settings))
        rows.append((chunk.tiles, torch.cat([torch.bmm(w, f[chunk.gauss]), (1 - t_final)[..., None]], dim=-1)))
    out = features.new_zeros(plan.num_tiles, plan.tile_size**2, d + 1)
    if rows:
        tiles = torch.cat([t for t, _ in rows])
        out = out.index_put((tiles,), torch.cat([r for _, r in rows]))
    img = _to_image(out, plan)
    return img[..., :d], img[..., d]
