"""Compiled CPU backend: binning, compositing forward and backward in C++ with OpenMP.

The extension (``render/cpu/raster.cpp``) is built on first use and cached (:mod:`sgs_slam_core.native`:
about a minute, keyed by the source, flags, torch and CPU). Set ``SGS_SLAM_NO_CPP=1`` to never build it.
Importing this module builds nothing.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from types import ModuleType
from typing import Any

import torch
from torch import Tensor

from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.native import NativeExtension
from sgs_slam_core.render.settings import RenderSettings

__all__ = [
    "EXTENSION",
    "WorldRenderState",
    "composite_cpu",
    "extension",
    "is_available",
    "render_world_isotropic_cpu",
    "unavailable_reason",
    "world_isotropic_backward",
    "world_isotropic_forward",
]

EXTENSION = NativeExtension("render", Path(__file__).with_name("cpu") / "raster.cpp", "the CPU renderer")


def extension() -> ModuleType:
    """The compiled module, building it on first call; raises :class:`BackendUnavailableError`."""
    return EXTENSION.module()


def build_variant(tag: str, extra_cflags: tuple[str, ...]) -> ModuleType:
    """The kernels built with extra compiler flags under their own cache name (about a minute).

    For tests of the code paths other CPUs take, e.g. ``("-mno-avx512f",)`` for the AVX2 build on
    an AVX-512 machine; :func:`extension` is unaffected. Raises what the build raises.
    """
    return EXTENSION.variant(tag, extra_cflags)


def is_available() -> bool:
    """True when the extension is (or can be) built; the first call may take a minute."""
    return EXTENSION.is_available()


def unavailable_reason() -> str:
    """Why the backend is unavailable (empty when it works or was never tried)."""
    return EXTENSION.unavailable_reason()


def _grads(grad_out: tuple[Tensor | None, ...]) -> tuple[list[Tensor | None], Tensor | None]:
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
        ext = extension()
        m, c, o, f = (t.detach().contiguous() for t in (means2d, conics, opacities, features))
        r = radii.detach().to(m.dtype).contiguous()
        tile = settings.cpu_tile(ext.max_tile(m.dtype == torch.float64))
        gids, offsets = ext.bin_gaussians(m, r, depths.detach(), width, height, tile, torch.get_num_threads())
        args = (width, height, tile, settings.alpha_min, settings.alpha_max, settings.extent_sigma**2,
                settings.min_transmittance, torch.get_num_threads())  # fmt: skip
        *images, sil, t_final, count = ext.composite_forward(m, c, o, r, f, gids, offsets, list(groups), *args)
        ctx.save_for_backward(m, c, o, r, f, gids, offsets, t_final, count)
        ctx.args, ctx.groups = args, list(groups)
        return (*images, sil)

    @staticmethod
    def backward(ctx: Any, *grad_out: Tensor | None) -> tuple[Tensor | None, ...]:  # type: ignore[override]
        m, c, o, r, f, gids, offsets, t_final, count = ctx.saved_tensors
        grads = extension().composite_backward(
            m, c, o, r, f, gids, offsets, t_final, count, ctx.groups, *_grads(grad_out), *ctx.args
        )
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

    Same maths as the torch backend; ``groups`` splits the ``D`` feature channels (e.g. colour,
    semantics, depth).
    """
    out = _CppComposite.apply(means2d, conics, opacities, features, radii, depths, width, height, settings, groups)
    return tuple(out)


@dataclass
class WorldRenderState:
    """What the backward of a compiled isotropic render needs (kernels' inputs and intermediates)."""

    tensors: tuple[Tensor, ...]  # means, pose, camera-frame means, scales, opacities, 2D records, tile lists, ...
    groups: list[int]  # channel groups: colour 3, semantics S, depth 1
    args: tuple[Any, ...]  # the compositor's size, tile, cuts and thread count
    cam: tuple[float, float, float, float, int, int]  # fx, fy, cx, cy, width, height
    settings: RenderSettings


def world_isotropic_forward(
    means: Tensor,  # [N, 3] world frame
    log_scales: Tensor,  # [N, 1]
    logit_opacities: Tensor,  # [N]
    colors: Tensor,  # [N, 3]
    semantics: Tensor,  # [N, S] (S = 0 renders no semantics)
    w2c: Tensor,  # [4, 4]
    k: Intrinsics,
    s: RenderSettings,
) -> tuple[tuple[Tensor, Tensor, Tensor, Tensor], WorldRenderState]:
    """(colour [H, W, 3], semantic [H, W, S], depth [H, W, 1], silhouette [H, W]) and the backward's state.

    No autograd: :class:`_CppWorldIsotropicRender` wraps this, and the direct mapping step
    (``slam/direct_step.py``) calls it with :func:`world_isotropic_backward` itself.
    """
    ext, threads = extension(), torch.get_num_threads()
    m, ls, lo, col, sem, pose = (t.detach() for t in (means, log_scales, logit_opacities, colors, semantics, w2c))
    cam = (k.fx, k.fy, k.cx, k.cy, k.width, k.height)
    mc, sc, op, feats, m2d, con, rad = ext.prepare_world_isotropic(
        m, ls, lo, col, sem, pose, *cam, s.near_plane, s.eps2d, s.alpha_min, s.extent_sigma, threads
    )
    tile = s.cpu_tile(ext.max_tile(m.dtype == torch.float64))
    gids, offsets = ext.bin_gaussians(m2d, rad, feats[:, -1], k.width, k.height, tile, threads)
    args = (k.width, k.height, tile, s.alpha_min, s.alpha_max, s.extent_sigma**2, s.min_transmittance, threads)
    groups = [3, sem.shape[1], 1]
    color, semantic, depth, sil, t_final, count = ext.composite_forward(
        m2d, con, op, rad, feats, gids, offsets, groups, *args
    )
    state = WorldRenderState((m, pose, mc, sc, op, m2d, con, rad, feats, gids, offsets, t_final, count), groups, args,
                             cam, s)  # fmt: skip
    return (color, semantic, depth, sil), state


def world_isotropic_backward(
    state: WorldRenderState,
    grad_out: tuple[Tensor | None, ...],  # gradients of (colour, semantic, depth, silhouette); None = 0
    need_params: bool,
    need_pose: bool,
) -> tuple[Tensor | None, ...]:  # d means, d log_scales [N, 1], d logit_opacities, d colors, d semantics, d w2c
    """Gradients of :func:`world_isotropic_forward`'s inputs (None where not needed)."""
    m, pose, mc, sc, op, m2d, con, rad, feats, gids, offsets, t_final, count = state.tensors
    ext, s = extension(), state.settings
    rows = ext.composite_backward(m2d, con, op, rad, feats, gids, offsets, t_final, count, state.groups,
                                  *_grads(grad_out), *state.args)  # fmt: skip
    g_m, g_ls, g_lo, g_col, g_sem, g_pose = ext.world_isotropic_backward(
        m, pose, mc, sc, op, rows, state.groups[1], need_params, need_pose, *state.cam, s.near_plane, s.eps2d,
        torch.get_num_threads(),
    )  # fmt: skip
    pose_grad = g_pose if need_pose else None
    if not need_params:  # tracking: the map is fixed, only the pose gets a gradient
        return None, None, None, None, None, pose_grad
    return g_m, g_ls[:, None], g_lo, g_col, g_sem, pose_grad


class _CppWorldIsotropicRender(torch.autograd.Function):
    """The map's isotropic parameters and the pose in, images out, all in C++.

    Camera transform, activations, projection, binning and compositing, and their gradients: no
    per-Gaussian tensor op runs in PyTorch per render (those cost ~3 ms of ~15 at 38k Gaussians).
    """

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
        ctx.state = replace(state, tensors=())
        return images

    @staticmethod
    def backward(ctx: Any, *grad_out: Tensor | None) -> tuple[Tensor | None, ...]:  # type: ignore[override]
        need_params, need_pose = any(ctx.needs_input_grad[:5]), ctx.needs_input_grad[5]
        state = replace(ctx.state, tensors=ctx.saved_tensors)
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
) -> tuple[Tensor, Tensor, Tensor, Tensor]:  # colour [H, W, 3], semantic [H, W, S], depth [H, W, 1], sil [H, W]
    """An isotropic map rendered from its own parameters, everything in the compiled kernels."""
    return tuple(_CppWorldIsotropicRender.apply(means, log_scales, logit_opacities, colors, semantics, w2c,
                                                intrinsics, settings))  # fmt: skip
