"""Tracking and mapping losses (SGS-SLAM's definitions)."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from sgs_slam_core.metrics.image import ssim
from sgs_slam_core.render.api import RenderOutput
from sgs_slam_core.slam.frame_data import FrameTensors
from sgs_slam_core.slam.settings import MappingSettings, TrackingSettings

__all__ = ["TrackingLoss", "mapping_loss", "tracking_loss", "tracking_mask"]


@dataclass
class TrackingLoss:
    """The scalar to minimise and what the failure guard looks at."""

    total: Tensor  # scalar
    mask_fraction: float  # fraction of pixels in the loss
    depth_residual_m: float  # mean |D - D_gt| over the mask


def tracking_mask(out: RenderOutput, frame: FrameTensors, sil_threshold: float) -> Tensor:  # [H, W] bool
    """Pixels with measured depth that the map explains with confidence (silhouette > threshold)."""
    return frame.valid & (out.silhouette.detach() > sil_threshold) & torch.isfinite(out.depth.detach())


def tracking_loss(out: RenderOutput, frame: FrameTensors, s: TrackingSettings, use_semantics: bool) -> TrackingLoss:
    """L1 **sums** over the mask: w_d |D - D_gt| + w_c |C - C_gt| + w_s |S - S_gt| (as the reference)."""
    mask = tracking_mask(out, frame, s.sil_threshold)
    count = int(mask.sum())
    depth_err = (out.depth - frame.depth).abs()[mask]
    total = s.weight_depth * depth_err.sum()
    total = total + s.weight_color * (out.color - frame.rgb).abs()[mask].sum()
    if use_semantics and frame.semantic is not None and s.weight_semantic > 0:
        total = total + s.weight_semantic * (out.semantic - frame.semantic).abs()[mask].sum()
    residual = float(depth_err.detach().mean()) if count else float("inf")
    return TrackingLoss(total, count / mask.numel(), residual)


def _photometric(pred: Tensor, target: Tensor, ignore: Tensor | None, ssim_weight: float) -> Tensor:
    if ignore is not None:  # ignored pixels match the prediction: no L1 error and no gradient there
        target = torch.where(ignore[..., None], pred.detach(), target)
    loss = (pred - target).abs().mean()
    if ssim_weight > 0:
        loss = (1 - ssim_weight) * loss + ssim_weight * (1 - ssim(pred, target, padding="same"))
    return loss


def mapping_loss(out: RenderOutput, frame: FrameTensors, s: MappingSettings, use_semantics: bool) -> Tensor:
    """w_d mean|D - D_gt| (valid depth) + w_c [(1-a) L1 + a (1 - SSIM)](C) + w_s [same](S).

    Colour and semantics count every pixel except ignored ones (edit locks).
    """
    valid = frame.valid & torch.isfinite(out.depth)
    loss = s.weight_depth * (out.depth - frame.depth).abs()[valid].mean() if bool(valid.any()) else out.depth.sum() * 0
    loss = loss + s.weight_color * _photometric(out.color, frame.rgb, frame.ignore, s.ssim_weight)
    if use_semantics and frame.semantic is not None and s.weight_semantic > 0:
        loss = loss + s.weight_semantic * _photometric(out.semantic, frame.semantic, frame.ignore, s.ssim_weight)
    return loss
