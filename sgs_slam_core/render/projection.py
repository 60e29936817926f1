"""EWA projection of camera-frame 3D Gaussians to 2D image-plane Gaussians (differentiable)."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.render.settings import RenderSettings

__all__ = ["Projection", "frustum_candidates", "project_gaussians"]


@dataclass
class Projection:
    """2D footprints of N Gaussians in one camera.

    ``radii`` is 0 for culled Gaussians (behind the near plane, transparent, or off-screen is decided
    later by tiling); it carries no gradient.
    """

    means2d: Tensor  # [N, 2] pixel coordinates (u, v)
    conics: Tensor  # [N, 3] inverse 2D covariance (A, B, C): q = A dx^2 + 2 B dx dy + C dy^2
    depths: Tensor  # [N] camera-frame z of the centres (m)
    opacities: Tensor  # [N] in [0, 1]
    radii: Tensor  # [N] footprint radius in pixels (no grad)


def project_gaussians(
    means_cam: Tensor,  # [N, 3] camera frame
    opacities: Tensor,  # [N] in [0, 1]
    intrinsics: Intrinsics,
    settings: RenderSettings,
    scales: Tensor | None = None,  # [N] isotropic standard deviation (m)
    covars_cam: Tensor | None = None,  # [N, 3, 3] camera-frame covariance (anisotropic)
) -> Projection:
    """Project with the local affine (EWA) approximation used by 3DGS.

    Exactly one of ``scales`` (isotropic: the covariance s^2 I needs no rotation) and ``covars_cam``
    must be given. The Jacobian's x/z, y/z are clamped to 1.3x the field of view, as in 3DGS/gsplat,
    so Gaussians far outside the image do not get huge footprints.
    """
    if (scales is None) == (covars_cam is None):
        raise ValueError("give exactly one of scales and covars_cam")
    fx, fy, cx, cy = intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy
    x, y, z = means_cam.unbind(-1)
    in_front = z > settings.near_plane
    z_safe = torch.where(in_front, z, torch.ones_like(z))
    x_over_z, y_over_z = x / z_safe, y / z_safe
    u = fx * x_over_z + cx
    v = fy * y_over_z + cy

    (lim_x_lo, lim_x_hi), (lim_y_lo, lim_y_hi) = _tangent_limits(intrinsics)
    tx = x_over_z.clamp(lim_x_lo, lim_x_hi)
    ty = y_over_z.clamp(lim_y_lo, lim_y_hi)
    inv_z = 1.0 / z_safe
    if scales is not None:
        # J J^T s^2 with J = [[fx/z, 0, -fx tx/z], [0, fy/z, -fy ty/z]].
        s2 = (scales * inv_z) ** 2
        a = s2 * fx * fx * (1 + tx * tx)
        b = s2 * fx * fy * tx * ty
        c = s2 * fy * fy * (1 + ty * ty)
    else:
        zero = torch.zeros_like(z)
        jac = torch.stack([fx * inv_z, zero, -fx * tx * inv_z, zero, fy * inv_z, -fy * ty * inv_z], dim=-1).reshape(
            -1, 2, 3
        )
        cov2d = jac @ covars_cam @ jac.transpose(1, 2)
        a, b, c = cov2d[:, 0, 0], cov2d[:, 0, 1], cov2d[:, 1, 1]
    a = a + settings.eps2d
    c = c + settings.eps2d
    det = (a * c - b * b).clamp_min(1e-12)
    conics = torch.stack([c / det, -b / det, a / det], dim=-1)

    return Projection(
        means2d=torch.stack([u, v], dim=-1),
        conics=conics,
        depths=z,
        opacities=opacities,
        radii=_radii(a, b, c, opacities, in_front, settings),
    )


def _tangent_limits(k: Intrinsics) -> tuple[tuple[float, float], tuple[float, float]]:
    """The clamp of x/z and y/z (low, high): the field of view widened by 0.3 of its half-tangent a side."""
    tan_x, tan_y = 0.5 * k.width / k.fx, 0.5 * k.height / k.fy
    x = (-(k.cx + 0.5) / k.fx - 0.3 * tan_x, (k.width - k.cx - 0.5) / k.fx + 0.3 * tan_x)
    y = (-(k.cy + 0.5) / k.fy - 0.3 * tan_y, (k.height - k.cy - 0.5) / k.fy + 0.3 * tan_y)
    return x, y


@torch.no_grad()
def _radii(
    a: Tensor, b: Tensor, c: Tensor, opacities: Tensor, in_front: Tensor, settings: RenderSettings
) -> Tensor:  # [N] px, 0 = culled
    """Footprint radii of the dilated 2D covariances [[a, b], [b, c]] (no grad)."""
    lam_max = 0.5 * (a + c) + torch.sqrt((0.5 * (a - c)) ** 2 + b * b)
    # Opacity-aware extent: beyond sqrt(2 ln(o / alpha_min)) sigma the alpha is below alpha_min.
    ratio = (opacities / settings.alpha_min).clamp_min(1.0)
    extent2 = torch.minimum(2 * torch.log(ratio), torch.full_like(ratio, settings.extent_sigma**2))
    radii = torch.sqrt(extent2 * lam_max)
    visible = in_front & (opacities >= settings.alpha_min) & torch.isfinite(radii)
    return torch.where(visible, radii, torch.zeros_like(radii))


@torch.no_grad()
def frustum_candidates(
    means: Tensor,  # [N, 3] world frame
    log_scales: Tensor,  # [N, 1] or [N] isotropic log standard deviation (log m)
    w2c: Tensor,  # [4, 4]
    intrinsics: Intrinsics,
    settings: RenderSettings,
) -> Tensor:  # [M] int64, ascending
    """The Gaussians whose footprint may touch the image: every one a render composites is among them.

    Left out: those at or behind the near plane, and those whose projected centre lies farther
    outside the image than a bound on :func:`project_gaussians`' radius: ``extent_sigma`` standard
    deviations of the largest spread the clamped Jacobian allows, the scale rounded up to a power of
    two, with 1 % and 1 px of slack. The reference of the compiled renderer's culling.
    """
    k = intrinsics
    cam = means @ w2c[:3, :3].T + w2c[:3, 3]
    x, y, z = cam.unbind(-1)
    tx, ty = (max(abs(lo), abs(hi)) for lo, hi in _tangent_limits(k))
    k2 = k.fx**2 * (1 + tx * tx) + k.fy**2 * (1 + ty * ty) + k.fx * k.fy * tx * ty
    exponent = (torch.floor(log_scales.reshape(-1) * 1.44269504) + 1.0).nan_to_num(127.0).clamp(-126.0, 127.0)
    inv_z = 1.0 / z
    rs = torch.exp2(exponent) * inv_z
    r = 1.01 * torch.sqrt(settings.extent_sigma**2 * (rs * rs * k2 + 2.0 * settings.eps2d)) + 1.0
    u, v = k.fx * (x * inv_z) + k.cx, k.fy * (y * inv_z) + k.cy
    outside = (u + r < 0) | (u - r > k.width - 1) | (v + r < 0) | (v - r > k.height - 1)
    return torch.nonzero(~(z <= settings.near_plane) & ~outside).squeeze(1)  # NaNs stay in
