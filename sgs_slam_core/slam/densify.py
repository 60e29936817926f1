"""Gaussians from pixels: first-frame initialisation and densification of unexplained pixels."""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.geometry.camera import backproject
from sgs_slam_core.render.api import RenderOutput
from sgs_slam_core.slam.frame_data import FrameTensors
from sgs_slam_core.slam.settings import DensifySettings

__all__ = ["densify_mask", "gaussians_from_pixels"]


def densify_mask(out: RenderOutput, frame: FrameTensors, s: DensifySettings) -> Tensor:  # [H, W] bool
    """Pixels needing new Gaussians: silhouette below threshold, or new geometry in front.

    The depth test follows the reference: rendered depth greater than measured and the absolute
    error above ``depth_error_factor`` x the median error over all pixels (invalid ones as 0).
    """
    sil, depth = out.silhouette.detach(), out.depth.detach()
    valid = frame.valid
    err = torch.where(valid, (frame.depth - depth).abs(), torch.zeros_like(depth))
    in_front = (depth > frame.depth) & (err > s.depth_error_factor * err.median())
    return valid & ((sil < s.sil_threshold) | in_front)


def gaussians_from_pixels(
    frame: FrameTensors,
    c2w: Tensor,  # [4, 4]
    mask: Tensor,  # [H, W] bool
    num_semantic: int,
    settings: DensifySettings,
    anisotropic: bool = False,
    generator: torch.Generator | None = None,
) -> GaussianMap:
    """One Gaussian per masked pixel, initialised from that pixel.

    Centre back-projected with ``c2w``, radius = depth / mean focal length (one pixel's footprint),
    colour, semantic target and class id from the pixel.
    """
    k = frame.intrinsics
    depth = torch.where(mask, frame.depth, torch.zeros_like(frame.depth))
    points, valid = backproject(depth, k, c2w)
    idx = torch.nonzero(valid.reshape(-1)).squeeze(1)
    if settings.max_new_per_frame is not None and idx.numel() > settings.max_new_per_frame:
        on = generator.device if generator is not None else idx.device  # the generator's device decides the draw
        pick = torch.randperm(idx.numel(), generator=generator, device=on)[: settings.max_new_per_frame].to(idx.device)
        idx, points = idx[pick], points[pick]
    n = idx.numel()
    device, dtype = frame.rgb.device, frame.rgb.dtype
    radius = depth.reshape(-1)[idx] / (0.5 * (k.fx + k.fy))
    colors = frame.rgb.reshape(-1, 3)[idx]
    if frame.semantic is not None and num_semantic:
        semantics = frame.semantic.reshape(-1, num_semantic)[idx]
        labels = frame.labels.reshape(-1)[idx]  # type: ignore[union-attr]
    else:
        semantics = torch.zeros(n, num_semantic, device=device, dtype=dtype)
        labels = torch.zeros(n, dtype=torch.long, device=device)
    log_scale = torch.log(radius.clamp_min(1e-6))[:, None]
    logit = math.log(settings.initial_opacity / (1 - settings.initial_opacity))
    return GaussianMap(
        means=points.to(dtype),
        log_scales=log_scale.expand(n, 3).contiguous() if anisotropic else log_scale,
        logit_opacities=torch.full((n,), logit, device=device, dtype=dtype),
        colors=colors,
        semantics=semantics,
        labels=labels,
        birth_frame=torch.full((n,), frame.index, dtype=torch.long, device=device),
        quats=torch.tensor([1.0, 0.0, 0.0, 0.0], device=device, dtype=dtype).expand(n, 4).contiguous()
        if anisotropic
        else None,
    )


def scene_radius(first_depth: np.ndarray, depth_ratio: float) -> float:
    """SplaTAM's scene radius: max first-frame depth / ratio (m); used to prune huge Gaussians."""
    valid = first_depth[first_depth > 0]
    return float(valid.max() / depth_ratio) if valid.size else 1.0
