"""The compiled CPU renderer: binning, compositing forward and backward in C++ with OpenMP.

Isotropic maps go whole into the kernels (camera transform, activations, projection, compositing
and every gradient, the pose's included); anisotropic maps are projected in PyTorch and composited
in C++. The extension (``raster.cpp``) is built on first use (:mod:`sgs_slam_core.native`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, NamedTuple

import torch
from torch import Tensor

from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.kernels.cpu.extensions import RENDER
from sgs_slam_core.render.settings import RenderSettings

__all__ = [
    "CameraArgs",
    "CompositeArgs",
    "RenderImages",
    "WorldRenderState",
    "WorldTensors",
    "composite_cpu",
    "frustum_cull",
    "render_world_isotropic_cpu",
    "world_isotropic_backward",
    "world_isotropic_forward",
]


class CompositeArgs(NamedTuple):
    """The compositor's scalar arguments, in its order."""

    width: int
    height: int
    tile: int  # tile side (px)
    alpha_min: float
    alpha_max: float
    extent_sq: float  # footprint cut-off squared (standard deviations^2)
    min_transmittance: float
    threads: int

    @staticmethod
    def of(s: RenderSettings, width: int, height: int, tile: int, threads: int) -> CompositeArgs:
        """The arguments for an image of ``width`` x ``height`` with settings ``s``."""
        extent_sq = s.extent_sigma**2
        return CompositeArgs(width, height, tile, s.alpha_min, s.alpha_max, extent_sq, s.min_transmittance, threads)


class CameraArgs(NamedTuple):
    """The pinhole camera as the world-frame kernels take it."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    @staticmethod
    def of(k: Intrinsics) -> CameraArgs:
        """The arguments of intrinsics ``k``."""
        return CameraArgs(k.fx, k.fy, k.cx, k.cy, k.width, k.height)


class WorldTensors(NamedTuple):
    """A compiled isotropic render's inputs and intermediates that its backward reads.

    Per-Gaussian rows are those of the Gaussians that may touch the image (:func:`frustum_cull`):
    ``M`` of the map's ``N`` (``means`` excepted).
    """

    means: Tensor  # [N, 3] world frame, the whole map's
    w2c: Tensor  # [4, 4]
    means_cam: Tensor  # [M, 3] camera frame
    scales: Tensor  # [M]
    opacities: Tensor  # [M]
    means2d: Tensor  # [M, 2]
    conics: Tensor  # [M, 3]
    radii: Tensor  # [M]
    features: Tensor  # [M, 3 + S + 1] colour, semantics, depth
    gids: Tensor  # [I] int32, Gaussians per tile intersection, depth-sorted per tile
    offsets: Tensor  # [T + 1] int64, each tile's range in gids
    t_final: Tensor  # [H, W] transmittance after the last blended Gaussian
    count: Tensor  # [H, W] int32, Gaussians blended per pixel
    ids: Tensor | None  # [M] int64, the map's rows the rows above are (None: every row, M = N)


class RenderImages(NamedTuple):
    """A compiled isotropic render's images."""

    color: Tensor  # [H, W, 3]
    semantic: Tensor  # [H, W, S]
    depth: Tensor  # [H, W, 1]
    silhouette: Tensor  # [H, W]


@dataclass
class WorldRenderState:
    """What the backward of a compiled isotropic render needs."""

    tensors: WorldTensors
    groups: list[int]  # channel groups: colour 3, semantics S, depth 1
    num_gaussians: int  # N, the map's (the gradients' rows)
    args: CompositeArgs
    cam: CameraArgs
    settings: RenderSettings


# Culling pays when it leaves out at least this share of the map: below, scattering the kept rows'
# gradients back costs about what the kernels save on the rest.
CULL_MIN_SHARE = 0.1


def frustum_cull(
    means: Tensor,  # [N, 3] world frame
    log_scales: Tensor,  # [N, 1]
    w2c: Tensor,  # [4, 4]
    cam: CameraArgs,
    s: RenderSettings,
) -> Tensor | None:  # [M] int64 ascending, or None: every Gaussian
    """The Gaussians that may touch the image, by ``frustum_candidates`` in ``raster.cpp``.

    Its PyTorch reference is :func:`sgs_slam_core.render.projection.frustum_candidates`. A render
    of these alone is the whole map's, bit for bit: the kernels composite the kept ones in the same
    order and skip the rest. The cost of a render then follows what the camera sees, not the map's
    size. None (no culling) for double maps and when culling would leave out less than
    ``CULL_MIN_SHARE`` of the map.
    """
    if means.dtype != torch.float32:
        return None
    cuts = (s.near_plane, s.eps2d, s.extent_sigma, torch.get_num_threads())
    ids = RENDER.module().frustum_candidates(means, log_scales, w2c, *cam, *cuts)
    return None if len(ids) > (1.0 - CULL_MIN_SHARE) * len(means) else ids


def _uncull(ids: Tensor | None, n: int, grads: tuple[Tensor, ...]) -> tuple[Tensor, ...]:  # ids [M]; grads [M, ...]
    """Gradients of the kept rows as the whole map's ``[N, ...]``: exact zeros for the culled Gaussians."""
    if ids is None:
        return grads
    return tuple(g.new_zeros((n, *g.shape[1:])).index_copy_(0, ids, g) for g in grads)


def _max_tile(ext: Any, dtype: torch.dtype, s: RenderSettings) -> int:
    return s.cpu_tile(ext.max_tile(dtype == torch.float64))


def _split_grads(grad_out: tuple[Tensor | None, ...]) -> tuple[list[Tensor | None], Tensor | None]:
    """The outputs' gradients as the kernels take them: (one per channel group, silhouette's); None = 0."""
    return list(grad_out[:-1]), grad_out[-1]


class _CppComposite(torch.autograd.Function):
    @staticmethod
    def forward(  # type: ignore[override]
        ctx: Any,
        means2d: Tensor,  # [N, 2]
        conics: Tensor,  # [N, 3]
        opacities: Tensor,  # [N]
        features: Tensor,  # [N, D]
        radii: Tensor,  # [N] (no grad)
        depths: Tensor,  # [N] (sort key, no grad)
        width: int,
        height: int,
        settings: RenderSettings,
        groups: tuple[int, ...],
    ) -> tuple[Tensor, ...]:
        ext, threads = RENDER.module(), torch.get_num_threads()
        m, c, o, f = (t.detach().contiguous() for t in (means2d, conics, opacities, features))
        r = radii.detach().to(m.dtype).contiguous()
        tile = _max_tile(ext, m.dtype, settings)
        gids, offsets = ext.bin_gaussians(m, r, depths.detach(), width, height, tile, threads)
        args = CompositeArgs.of(settings, width, height, tile, threads)
        *images, sil, t_final, count = ext.composite_forward(m, c, o, r, f, gids, offsets, list(groups), *args)
        ctx.save_for_backward(m, c, o, r, f, gids, offsets, t_final, count)
        ctx.args, ctx.groups = args, list(groups)
        return (*images, sil)

    @staticmethod
    def backward(ctx: Any, *grad_out: Tensor | None) -> tuple[Tensor | None, ...]:  # type: ignore[override]
        saved = ctx.saved_tensors  # means2d, conics, opacities, radii, features, gids, offsets, t_final, count
        grads = RENDER.module().composite_backward(*saved, ctx.groups, *_split_grads(grad_out), *ctx.args)
        return grads[:, 0:2], grads[:, 2:5], grads[:, 5], grads[:, 6:], None, None, None, None, None, None


def composite_cpu(
    means2d: Tensor,  # [N, 2]
    conics: Tensor,  # [N, 3]
    opacities: Tensor,  # [N]
    features: Tensor,  # [N, D]
    radii: Tensor,  # [N]
    depths: Tensor,  # [N]
    width: int,
    height: int,
    settings: RenderSettings,
    groups: tuple[int, ...],
) -> tuple[Tensor, ...]:
    """``(*image channel groups [H, W, g], silhouette [H, W])`` by the compiled kernels.

    Same maths as ``render/composite.py``; ``groups`` splits the ``D`` feature channels (e.g. colour,
    semantics, depth).
    """
    out = _CppComposite.apply(means2d, conics, opacities, features, radii, depths, width, height, settings, groups)
    return tuple(out)


def world_isotropic_forward(
    means: Tensor,  # [N, 3] world frame
    log_scales: Tensor,  # [N, 1]
    logit_opacities: Tensor,  # [N]
    colors: Tensor,  # [N, 3]
    semantics: Tensor,  # [N, S] (S = 0 renders no semantics)
    w2c: Tensor,  # [4, 4]
    k: Intrinsics,
    s: RenderSettings,
) -> tuple[RenderImages, WorldRenderState]:
    """The images and the backward's state, without autograd.

    :class:`_CppWorldIsotropicRender` wraps this, and the direct mapping step (``mapping_step.py``)
    calls it with :func:`world_isotropic_backward` itself.
    """
    ext, threads = RENDER.module(), torch.get_num_threads()
    m, ls, lo, col, sem, pose = (t.detach() for t in (means, log_scales, logit_opacities, colors, semantics, w2c))
    cam = CameraArgs.of(k)
    ids = frustum_cull(m, ls, pose, cam, s)
    cuts = (s.near_plane, s.eps2d, s.alpha_min, s.extent_sigma, threads)
    mc, sc, op, feats, m2d, con, rad = ext.prepare_world_rows(m, ls, lo, col, sem, pose, *cam, *cuts, ids)
    tile = _max_tile(ext, m.dtype, s)
    gids, offsets = ext.bin_gaussians(m2d, rad, feats[:, -1], k.width, k.height, tile, threads)
    args = CompositeArgs.of(s, k.width, k.height, tile, threads)
    groups = [3, sem.shape[1], 1]
    *images, t_final, count = ext.composite_forward(m2d, con, op, rad, feats, gids, offsets, groups, *args)
    tensors = WorldTensors(
        means=m,
        w2c=pose,
        means_cam=mc,
        scales=sc,
        opacities=op,
        means2d=m2d,
        conics=con,
        radii=rad,
        features=feats,
        gids=gids,
        offsets=offsets,
        t_final=t_final,
        count=count,
        ids=ids,
    )
    return RenderImages(*images), WorldRenderState(tensors, groups, len(means), args, cam, s)


def world_isotropic_backward(
    state: WorldRenderState,
    grad_out: tuple[Tensor | None, ...],  # gradients of (colour, semantic, depth, silhouette); None = 0
    need_params: bool,
    need_pose: bool,
) -> tuple[Tensor | None, ...]:  # d means, d log_scales [N, 1], d logit_opacities, d colors, d semantics, d w2c
    """Gradients of :func:`world_isotropic_forward`'s inputs (None where not needed)."""
    t, ext, s = state.tensors, RENDER.module(), state.settings
    splats = (t.means2d, t.conics, t.opacities, t.radii, t.features, t.gids, t.offsets, t.t_final, t.count)
    rows = ext.composite_backward(*splats, state.groups, *_split_grads(grad_out), *state.args)
    means = t.means if t.ids is None else t.means.index_select(0, t.ids)  # [M, 3]
    world = (means, t.w2c, t.means_cam, t.scales, t.opacities, rows, state.groups[1], need_params, need_pose)
    cuts = (s.near_plane, s.eps2d, torch.get_num_threads())
    g_m, g_ls, g_lo, g_col, g_sem, g_pose = ext.world_isotropic_backward(*world, *state.cam, *cuts)
    pose_grad = g_pose if need_pose else None
    if not need_params:  # tracking: the map is fixed, only the pose gets a gradient
        return None, None, None, None, None, pose_grad
    g_m, g_ls, g_lo, g_col, g_sem = _uncull(t.ids, state.num_gaussians, (g_m, g_ls[:, None], g_lo, g_col, g_sem))
    return g_m, g_ls, g_lo, g_col, g_sem, pose_grad


class _CppWorldIsotropicRender(torch.autograd.Function):
    """The map's isotropic parameters and the pose in, images out, all in C++ (no per-Gaussian PyTorch op)."""

    @staticmethod
    def forward(  # type: ignore[override]
        ctx: Any,
        means: Tensor,  # [N, 3] world frame
        log_scales: Tensor,  # [N, 1]
        logit_opacities: Tensor,  # [N]
        colors: Tensor,  # [N, 3]
        semantics: Tensor,  # [N, S] (S = 0 renders no semantics)
        w2c: Tensor,  # [4, 4]
        k: Intrinsics,
        s: RenderSettings,
    ) -> tuple[Tensor, ...]:
        images, state = world_isotropic_forward(means, log_scales, logit_opacities, colors, semantics, w2c, k, s)
        ctx.save_for_backward(*state.tensors)  # (autograd checks that nothing changed them in place)
        ctx.state = replace(state, tensors=None)
        return tuple(images)

    @staticmethod
    def backward(ctx: Any, *grad_out: Tensor | None) -> tuple[Tensor | None, ...]:  # type: ignore[override]
        need_params, need_pose = any(ctx.needs_input_grad[:5]), ctx.needs_input_grad[5]
        state = replace(ctx.state, tensors=WorldTensors(*ctx.saved_tensors))
        return (*world_isotropic_backward(state, grad_out, need_params, need_pose), None, None)


def render_world_isotropic_cpu(
    means: Tensor,  # [N, 3] world frame
    log_scales: Tensor,  # [N, 1]
    logit_opacities: Tensor,  # [N]
    colors: Tensor,  # [N, 3]
    semantics: Tensor,  # [N, S]; S = 0 skips the semantic channels
    w2c: Tensor,  # [4, 4]
    intrinsics: Intrinsics,
    settings: RenderSettings,
) -> RenderImages:
    """An isotropic map rendered from its own parameters, everything in the compiled kernels (autograd)."""
    params = (means, log_scales, logit_opacities, colors, semantics, w2c)
    return RenderImages(*_CppWorldIsotropicRender.apply(*params, intrinsics, settings))
