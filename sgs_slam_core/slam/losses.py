"""Tracking and mapping losses (SGS-SLAM's definitions)."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from sgs_slam_core.config.sections import MappingSettings, TrackingSettings
from sgs_slam_core.render.api import RenderOutput
from sgs_slam_core.slam.frame_data import FrameTensors
from sgs_slam_core.slam.fused_losses import (
    fused_available,
    fused_mapping_loss,
    fused_tracking_loss,
    mapping_loss_grads,
)
from sgs_slam_core.slam.photometric import photometric_loss

__all__ = [
    "TrackingLoss",
    "mapping_loss",
    "mapping_loss_and_grads",
    "mapping_loss_reference",
    "tracking_loss",
    "tracking_loss_reference",
    "tracking_mask",
]


@dataclass
class TrackingLoss:
    """The scalar to minimise and what the failure guard looks at; all on the frame's device (no host sync)."""

    total: Tensor  # [] differentiable
    pixels: Tensor  # [] int64, pixels in the mask
    depth_residual_m: Tensor  # [] mean |D - D_gt| over the mask (m), inf when the mask is empty


def tracking_mask(out: RenderOutput, frame: FrameTensors, sil_threshold: float) -> Tensor:  # [H, W] bool
    """Pixels with measured depth that the map explains with confidence (silhouette > threshold)."""
    return frame.valid & (out.silhouette.detach() > sil_threshold) & torch.isfinite(out.depth.detach())


def _semantic_term(use_semantics: bool, frame: FrameTensors, weight: float) -> bool:
    return use_semantics and frame.semantic is not None and weight > 0


def tracking_loss(out: RenderOutput, frame: FrameTensors, s: TrackingSettings, use_semantics: bool) -> TrackingLoss:
    """:func:`tracking_loss_reference`; in one C++ call and one autograd node on the CPU (``fused_losses``)."""
    if not fused_available(out.depth.device):
        return tracking_loss_reference(out, frame, s, use_semantics)
    semantic = _semantic_term(use_semantics, frame, s.weight_semantic)
    total, pixels, depth_sum = fused_tracking_loss(
        out.color, out.semantic if semantic else None, out.depth, out.silhouette, frame.valid, frame.rgb,
        frame.semantic if semantic else None, frame.depth, s.sil_threshold,
        (s.weight_depth, s.weight_color, s.weight_semantic),
    )  # fmt: skip
    residual = torch.where(pixels > 0, depth_sum / pixels.clamp(min=1), float("inf"))
    return TrackingLoss(total, pixels, residual)


def tracking_loss_reference(
    out: RenderOutput, frame: FrameTensors, s: TrackingSettings, use_semantics: bool
) -> TrackingLoss:
    """L1 **sums** over the mask: w_d |D - D_gt| + w_c |C - C_gt| + w_s |S - S_gt| (as the reference).

    Masked by ``where`` before the absolute value (not by indexing), so nothing waits for the device
    and pixels outside the mask (a NaN render included) get exactly zero gradient.
    """
    mask = tracking_mask(out, frame, s.sil_threshold)
    pixels = mask.sum()
    depth_err = torch.where(mask, out.depth - frame.depth, 0.0).abs()
    total = s.weight_depth * depth_err.sum()
    total = total + s.weight_color * torch.where(mask[..., None], out.color - frame.rgb, 0.0).abs().sum()
    if _semantic_term(use_semantics, frame, s.weight_semantic):
        sem_err = torch.where(mask[..., None], out.semantic - frame.semantic, 0.0).abs()
        total = total + s.weight_semantic * sem_err.sum()
    residual = torch.where(pixels > 0, depth_err.detach().sum() / pixels.clamp(min=1), float("inf"))
    return TrackingLoss(total, pixels, residual)


def mapping_loss(
    out: RenderOutput, frame: FrameTensors, s: MappingSettings, use_semantics: bool, scale: float = 1.0
) -> Tensor:
    """``scale`` x :func:`mapping_loss_reference`; one autograd node on the CPU (``fused_losses``)."""
    if not fused_available(out.color.device):
        return scale * mapping_loss_reference(out, frame, s, use_semantics)
    semantic, rgb, sem_target = _mapping_targets(out, frame, s, use_semantics)
    return fused_mapping_loss(
        out.color, out.semantic if semantic else None, out.depth, frame.valid, rgb, sem_target, frame.depth,
        (s.weight_depth, s.weight_color, s.weight_semantic), s.ssim_weight, scale,
    )  # fmt: skip


def mapping_loss_and_grads(
    out: RenderOutput, frame: FrameTensors, s: MappingSettings, use_semantics: bool, scale: float = 1.0
) -> tuple[Tensor, Tensor | None, Tensor | None, Tensor]:  # loss [], d colour, d semantic (None: no term), d depth
    """:func:`mapping_loss`'s value and its gradients with respect to the render, without autograd (CPU only)."""
    semantic, rgb, sem_target = _mapping_targets(out, frame, s, use_semantics)
    return mapping_loss_grads(
        out.color, out.semantic if semantic else None, out.depth, frame.valid, rgb, sem_target, frame.depth,
        (s.weight_depth, s.weight_color, s.weight_semantic), s.ssim_weight, scale, True,
    )  # fmt: skip


def _mapping_targets(
    out: RenderOutput, frame: FrameTensors, s: MappingSettings, use_semantics: bool
) -> tuple[bool, Tensor, Tensor | None]:  # semantic term on, colour target [H, W, 3], semantic target [H, W, S]
    """The fused loss's targets: ignored pixels match the render (no error, no gradient, as photometric_loss)."""
    semantic = _semantic_term(use_semantics, frame, s.weight_semantic)
    rgb, sem_target = frame.rgb, frame.semantic if semantic else None
    if frame.ignore is not None:
        rgb = torch.where(frame.ignore[..., None], out.color.detach(), rgb)
        if sem_target is not None:
            sem_target = torch.where(frame.ignore[..., None], out.semantic.detach(), sem_target)
    return semantic, rgb, sem_target


def mapping_loss_reference(out: RenderOutput, frame: FrameTensors, s: MappingSettings, use_semantics: bool) -> Tensor:
    """w_d mean|D - D_gt| (valid depth) + w_c [(1-a) L1 + a (1 - SSIM)](C) + w_s [same](S).

    Colour and semantics count every pixel except ignored ones (edit locks).
    """
    valid = frame.valid & torch.isfinite(out.depth)
    depth_err = torch.where(valid, out.depth - frame.depth, 0.0).abs().sum() / valid.sum().clamp(min=1)
    loss = s.weight_depth * depth_err
    loss = loss + s.weight_color * photometric_loss(out.color, frame.rgb, frame.ignore, s.ssim_weight)
    if _semantic_term(use_semantics, frame, s.weight_semantic):
        loss = loss + s.weight_semantic * photometric_loss(out.semantic, frame.semantic, frame.ignore, s.ssim_weight)
    return loss
