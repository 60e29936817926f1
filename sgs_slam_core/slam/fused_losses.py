"""The tracking and mapping losses on the CPU: one C++ call and one autograd node each.

Same values and gradients as the references in :mod:`sgs_slam_core.slam.losses` (tested against
them), without the ~15 small tensor ops and autograd nodes the references run per iteration:
measured on 2 cores at 160x120, the mapping loss with its backward 1.24 ms instead of 1.53 (before
the SSIM kernel's own speed-up; with the depth term in the same C++ call, 0.34 instead of 0.54 ms
against the SSIM kernel's 0.23-0.31), tracking's ~0.1 ms instead of 0.66. The loss is a scalar, so each
gradient is known once the loss is, and the backward only scales it. L1 terms use sign(x - y), the
subgradient autograd gives |x - y| (0 at 0).
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor

from sgs_slam_core.slam.photometric import EXTENSION, SIGMA, WINDOW

__all__ = ["fused_available", "fused_mapping_loss", "fused_tracking_loss", "mapping_loss_grads"]


class _Scaled(torch.autograd.Function):
    """A scalar whose gradients with respect to some inputs were computed with it (None = no input)."""

    @staticmethod
    def forward(ctx: Any, value: Tensor, grads: tuple[Tensor | None, ...], *inputs: Tensor | None) -> Tensor:  # type: ignore[override]
        ctx.save_for_backward(*grads)
        return value.clone()

    @staticmethod
    def backward(ctx: Any, grad_out: Tensor) -> tuple[Tensor | None, ...]:  # type: ignore[override]
        return (None, None, *(g * grad_out if g is not None else None for g in ctx.saved_tensors))


def fused_available(device: torch.device) -> bool:
    """True where these losses run: on the CPU, once the extension builds."""
    return device.type == "cpu" and EXTENSION.is_available()


def fused_tracking_loss(
    color: Tensor,  # [H, W, 3] rendered
    semantic: Tensor | None,  # [H, W, S] rendered, None = no semantic term
    depth: Tensor,  # [H, W] rendered
    silhouette: Tensor,  # [H, W] rendered
    valid: Tensor,  # [H, W] bool, measured depth (and not ignored)
    rgb: Tensor,  # [H, W, 3] measured
    sem_target: Tensor | None,  # [H, W, S] measured
    depth_target: Tensor,  # [H, W] measured (m)
    sil_threshold: float,
    weights: tuple[float, float, float],  # depth, colour, semantic
) -> tuple[Tensor, Tensor, Tensor]:  # loss [] differentiable, pixels [] int64, sum of |D - D_gt| [] (m)
    """w_d sum|D - D_gt| + w_c sum|C - C_gt| + w_s sum|S - S_gt| over valid & silhouette > threshold & finite D.

    As ``losses.tracking_loss_reference``, in one C++ call (CPU).
    """
    h, w = depth.shape
    if semantic is None or sem_target is None:
        semantic = sem_target = color.new_zeros(h, w, 0)
    total, pixels, depth_sum, g_color, g_sem, g_depth = EXTENSION.module().tracking_l1(
        color.detach(), semantic.detach(), depth.detach(), silhouette.detach(), rgb, sem_target, depth_target, valid,
        float(sil_threshold), *(float(x) for x in weights), torch.get_num_threads(),
    )  # fmt: skip
    grads = (g_color, g_sem if semantic.shape[2] else None, g_depth)
    return _Scaled.apply(total, grads, color, semantic if semantic.shape[2] else None, depth), pixels, depth_sum


def mapping_loss_grads(
    color: Tensor,  # [H, W, 3] rendered
    semantic: Tensor | None,  # [H, W, S] rendered, None = no semantic term
    depth: Tensor,  # [H, W] rendered
    valid: Tensor,  # [H, W] bool, measured depth (and not ignored)
    rgb: Tensor,  # [H, W, 3] measured (ignored pixels already replaced by the render)
    sem_target: Tensor | None,  # [H, W, S] measured, likewise
    depth_target: Tensor,  # [H, W] measured (m)
    weights: tuple[float, float, float],  # depth, colour, semantic
    ssim_weight: float,
    scale: float,
    need_grad: bool,
) -> tuple[Tensor, Tensor | None, Tensor | None, Tensor]:  # loss [], d colour, d semantic (None: no term), d depth
    """``scale`` x (w_d mean|D - D_gt| + w_c photometric(C) + w_s photometric(S)) and its gradients, no autograd.

    One C++ call (``mapping_loss`` in ``slam/cpu/photometric.cpp``, CPU only) computes the value and
    every gradient: the depth mean's ~10 tensor ops cost ~0.2 ms a mapping step on their own.
    ``need_grad`` False skips the colour and semantic gradients (None).
    """
    h, w = depth.shape
    if semantic is None or sem_target is None:
        semantic = sem_target = None
    empty = color.new_zeros(h, w, 0)
    total, g_color, g_sem, g_depth = EXTENSION.module().mapping_loss(
        color.detach(), empty if semantic is None else semantic.detach(), depth.detach(), valid, rgb,
        empty if sem_target is None else sem_target, depth_target, *(float(x) for x in weights), float(ssim_weight),
        float(scale), need_grad, WINDOW, SIGMA, torch.get_num_threads(),
    )  # fmt: skip
    return total, g_color if need_grad else None, g_sem if need_grad and semantic is not None else None, g_depth


def fused_mapping_loss(
    color: Tensor,  # [H, W, 3] rendered
    semantic: Tensor | None,  # [H, W, S] rendered, None = no semantic term
    depth: Tensor,  # [H, W] rendered
    valid: Tensor,  # [H, W] bool, measured depth (and not ignored)
    rgb: Tensor,  # [H, W, 3] measured (ignored pixels already replaced by the render)
    sem_target: Tensor | None,  # [H, W, S] measured, likewise
    depth_target: Tensor,  # [H, W] measured (m)
    weights: tuple[float, float, float],  # depth, colour, semantic
    ssim_weight: float,
    scale: float = 1.0,
) -> Tensor:  # [] differentiable
    """:func:`mapping_loss_grads` as one autograd node, as ``losses.mapping_loss``."""
    if semantic is None or sem_target is None:
        semantic = sem_target = None
    need_grad = color.requires_grad or (semantic is not None and semantic.requires_grad)
    total, g_color, g_sem, g_depth = mapping_loss_grads(
        color, semantic, depth, valid, rgb, sem_target, depth_target, weights, ssim_weight, scale, need_grad
    )
    sem_grad = g_sem if semantic is not None and semantic.requires_grad else None
    grads = (g_color if color.requires_grad else None, sem_grad, g_depth)
    return _Scaled.apply(total, grads, color, semantic, depth)
