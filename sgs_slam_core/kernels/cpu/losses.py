"""The SLAM's losses on the CPU: each value and its gradients in one C++ call (``photometric.cpp``).

Same values and gradients as :mod:`sgs_slam_core.kernels.losses` and :mod:`sgs_slam_core.kernels.photometric`
(tested against them). Each loss is a scalar, so its gradients are known once it is, and the
autograd backward only scales them. L1 terms use sign(x - y), the subgradient autograd gives
|x - y| (0 at 0).
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor

from sgs_slam_core.config.sections import MappingSettings, TrackingSettings
from sgs_slam_core.frame_data import FrameTensors
from sgs_slam_core.kernels.cpu.extensions import PHOTOMETRIC
from sgs_slam_core.kernels.losses import TrackingLoss, mapping_targets, semantic_term
from sgs_slam_core.kernels.photometric import SIGMA, WINDOW
from sgs_slam_core.render.output import RenderOutput

__all__ = ["MappingGrads", "mapping_loss", "mapping_loss_grads", "photometric_loss", "tracking_loss"]

MappingGrads = tuple[Tensor, Tensor | None, Tensor | None, Tensor]  # loss [], d colour, d semantic, d depth [H, W]


class _Scaled(torch.autograd.Function):
    """A scalar whose gradients with respect to some inputs were computed with it (None = no input)."""

    @staticmethod
    def forward(ctx: Any, value: Tensor, grads: tuple[Tensor | None, ...], *inputs: Tensor | None) -> Tensor:  # type: ignore[override]
        ctx.save_for_backward(*grads)
        return value.clone()

    @staticmethod
    def backward(ctx: Any, grad_out: Tensor) -> tuple[Tensor | None, ...]:  # type: ignore[override]
        return (None, None, *(g * grad_out if g is not None else None for g in ctx.saved_tensors))


def tracking_loss(out: RenderOutput, frame: FrameTensors, s: TrackingSettings, use_semantics: bool) -> TrackingLoss:
    """``losses.tracking_loss_reference`` in one C++ call and one autograd node."""
    h, w = out.depth.shape
    color, depth = out.color, out.depth
    semantic, sem_target = out.semantic, frame.semantic
    if not semantic_term(use_semantics, frame, s.weight_semantic):
        semantic = sem_target = color.new_zeros(h, w, 0)
    renders = (color.detach(), semantic.detach(), depth.detach(), out.silhouette.detach())
    targets = (frame.rgb, sem_target, frame.depth, frame.valid)
    weights = (float(s.weight_depth), float(s.weight_color), float(s.weight_semantic))
    total, pixels, depth_sum, g_color, g_sem, g_depth = PHOTOMETRIC.module().tracking_l1(
        *renders, *targets, float(s.sil_threshold), *weights, torch.get_num_threads()
    )
    has_sem = semantic.shape[2] > 0
    grads = (g_color, g_sem if has_sem else None, g_depth)
    total = _Scaled.apply(total, grads, color, semantic if has_sem else None, depth)
    residual = torch.where(pixels > 0, depth_sum / pixels.clamp(min=1), float("inf"))
    return TrackingLoss(total, pixels, residual)


def mapping_loss_grads(
    out: RenderOutput,
    frame: FrameTensors,
    s: MappingSettings,
    use_semantics: bool,
    scale: float,
    need_grad: bool,
) -> MappingGrads:
    """``scale`` x ``losses.mapping_loss_reference`` and its gradients with respect to the render, no autograd.

    ``need_grad`` False skips the colour and semantic gradients (None); the semantic one is None
    without a semantic term.
    """
    h, w = out.depth.shape
    targets = mapping_targets(out, frame, s, use_semantics)
    empty = out.color.new_zeros(h, w, 0)
    semantic = out.semantic.detach() if targets.semantic else empty
    sem_target = targets.semantic_target if targets.semantic else empty
    images = (out.color.detach(), semantic, out.depth.detach(), frame.valid, targets.rgb, sem_target, frame.depth)
    weights = (float(s.weight_depth), float(s.weight_color), float(s.weight_semantic), float(s.ssim_weight))
    total, g_color, g_sem, g_depth = PHOTOMETRIC.module().mapping_loss(
        *images, *weights, float(scale), need_grad, WINDOW, SIGMA, torch.get_num_threads()
    )
    return total, g_color if need_grad else None, g_sem if need_grad and targets.semantic else None, g_depth


def mapping_loss(
    out: RenderOutput, frame: FrameTensors, s: MappingSettings, use_semantics: bool, scale: float = 1.0
) -> Tensor:  # [] differentiable
    """:func:`mapping_loss_grads` as one autograd node."""
    semantic = semantic_term(use_semantics, frame, s.weight_semantic)
    sem_render = out.semantic if semantic else None
    need_grad = out.color.requires_grad or (sem_render is not None and sem_render.requires_grad)
    total, g_color, g_sem, g_depth = mapping_loss_grads(out, frame, s, use_semantics, scale, need_grad)
    sem_grad = g_sem if sem_render is not None and sem_render.requires_grad else None
    grads = (g_color if out.color.requires_grad else None, sem_grad, g_depth)
    return _Scaled.apply(total, grads, out.color, sem_render, out.depth)


def photometric_loss(
    pred: Tensor,  # [H, W, C] rendered, differentiable
    target: Tensor,  # [H, W, C] measured (no gradient)
    ignore: Tensor | None,  # [H, W] bool: pixels that count as matched (no error, no gradient)
    ssim_weight: float,
) -> Tensor:  # []
    """``slam.photometric.photometric_loss`` and its gradient in one C++ call."""
    if ignore is not None:
        target = torch.where(ignore[..., None], pred.detach(), target)
    return _FusedPhotometric.apply(pred, target.detach(), ssim_weight)


class _FusedPhotometric(torch.autograd.Function):
    @staticmethod
    def forward(ctx: Any, pred: Tensor, target: Tensor, ssim_weight: float) -> Tensor:  # type: ignore[override]
        need_grad = pred.requires_grad
        loss, grad = PHOTOMETRIC.module().photometric_loss(
            pred.detach(), target, float(ssim_weight), WINDOW, SIGMA, need_grad, torch.get_num_threads()
        )
        ctx.save_for_backward(grad if need_grad else None)
        return loss

    @staticmethod
    def backward(ctx: Any, grad_out: Tensor) -> tuple[Tensor | None, None, None]:  # type: ignore[override]
        (grad,) = ctx.saved_tensors
        return (grad * grad_out if grad is not None else None), None, None
