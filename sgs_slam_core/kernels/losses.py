"""Tracking and mapping losses (SGS-SLAM's definitions), in PyTorch.

These are the reference: the kernels (:mod:`sgs_slam_core.kernels`) compute them, the compiled CPU
kernels in one C++ call each; the SLAM calls ``kernels.tracking_loss`` and ``kernels.mapping_loss``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import torch
from torch import Tensor

from sgs_slam_core.config.sections import MappingSettings, TrackingSettings
from sgs_slam_core.frame_data import FrameTensors
from sgs_slam_core.kernels.photometric import SsimBlur, photometric_loss
from sgs_slam_core.render.output import RenderOutput

__all__ = [
    "MappingTargets",
    "MappingWeights",
    "MeasuredImages",
    "TrackingLoss",
    "mapping_inputs",
    "mapping_loss_of",
    "mapping_loss_reference",
    "mapping_targets",
    "semantic_term",
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


def semantic_term(use_semantics: bool, frame: FrameTensors, weight: float) -> bool:
    """True when the loss has a semantic term (asked for, measured, and weighted)."""
    return use_semantics and frame.semantic is not None and weight > 0


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
    if semantic_term(use_semantics, frame, s.weight_semantic):
        sem_err = torch.where(mask[..., None], out.semantic - frame.semantic, 0.0).abs()
        total = total + s.weight_semantic * sem_err.sum()
    residual = torch.where(pixels > 0, depth_err.detach().sum() / pixels.clamp(min=1), float("inf"))
    return TrackingLoss(total, pixels, residual)


@dataclass
class MappingTargets:
    """The mapping loss's image targets with ignored pixels replaced by the render (no error, no gradient)."""

    semantic: bool  # the loss has a semantic term
    rgb: Tensor  # [H, W, 3]
    semantic_target: Tensor | None  # [H, W, S], None without the semantic term


def mapping_targets(out: RenderOutput, frame: FrameTensors, s: MappingSettings, use_semantics: bool) -> MappingTargets:
    """The targets a one-call mapping loss compares the render with (as ``photometric_loss`` masks them)."""
    semantic = semantic_term(use_semantics, frame, s.weight_semantic)
    rgb, sem_target = frame.rgb, frame.semantic if semantic else None
    if frame.ignore is not None:
        rgb = torch.where(frame.ignore[..., None], out.color.detach(), rgb)
        if sem_target is not None:
            sem_target = torch.where(frame.ignore[..., None], out.semantic.detach(), sem_target)
    return MappingTargets(semantic, rgb, sem_target)


class MeasuredImages(NamedTuple):
    """What the mapping loss compares a render with: one frame's measured images.

    Unlike :class:`MappingTargets` (the one-call losses'), ignored pixels are not replaced yet.
    """

    rgb: Tensor  # [H, W, 3]
    depth: Tensor  # [H, W] m, 0 = invalid
    valid: Tensor  # [H, W] bool: measured depth, not ignored
    semantic: Tensor | None  # [H, W, S], None without the semantic term
    ignore: Tensor | None  # [H, W] bool: pixels that count as matched (no error, no gradient)


class MappingWeights(NamedTuple):
    """The mapping loss's term weights and its SSIM share."""

    depth: float
    color: float
    semantic: float
    ssim: float


def mapping_inputs(
    frame: FrameTensors, s: MappingSettings, use_semantics: bool
) -> tuple[MeasuredImages, MappingWeights]:
    """The frame's targets (semantics only where the loss has the term) and the settings' weights."""
    semantic = frame.semantic if semantic_term(use_semantics, frame, s.weight_semantic) else None
    target = MeasuredImages(frame.rgb, frame.depth, frame.valid, semantic, frame.ignore)
    return target, MappingWeights(s.weight_depth, s.weight_color, s.weight_semantic, s.ssim_weight)


def mapping_loss_of(
    color: Tensor,  # [H, W, 3] rendered
    depth: Tensor,  # [H, W] rendered
    semantic: Tensor,  # [H, W, S] rendered (unused without a target)
    target: MeasuredImages,
    w: MappingWeights,
    blur: SsimBlur = "band",
) -> Tensor:  # []
    """:func:`mapping_loss_reference` on tensors alone (the form ``torch.compile`` traces)."""
    valid = target.valid & torch.isfinite(depth)
    depth_err = torch.where(valid, depth - target.depth, 0.0).abs().sum() / valid.sum().clamp(min=1)
    loss = w.depth * depth_err + w.color * photometric_loss(color, target.rgb, target.ignore, w.ssim, blur)
    if target.semantic is not None:
        loss = loss + w.semantic * photometric_loss(semantic, target.semantic, target.ignore, w.ssim, blur)
    return loss


def mapping_loss_reference(
    out: RenderOutput, frame: FrameTensors, s: MappingSettings, use_semantics: bool, blur: SsimBlur = "band"
) -> Tensor:
    """w_d mean|D - D_gt| (valid depth) + w_c [(1-a) L1 + a (1 - SSIM)](C) + w_s [same](S).

    Colour and semantics count every pixel except ignored ones (edit locks); ``blur`` is the SSIM
    window's form (the same function either way, up to rounding).
    """
    target, weights = mapping_inputs(frame, s, use_semantics)
    return mapping_loss_of(out.color, out.depth, out.semantic, target, weights, blur)
