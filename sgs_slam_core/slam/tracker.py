"""Tracking: optimise the camera pose of one frame against the fixed map."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import torch
from torch.profiler import record_function

from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.render.api import render
from sgs_slam_core.render.settings import RenderSettings
from sgs_slam_core.slam.frame_data import FrameTensors
from sgs_slam_core.slam.losses import tracking_loss
from sgs_slam_core.slam.pose import PoseParameters
from sgs_slam_core.slam.settings import TrackingSettings

__all__ = ["TrackResult", "track"]


@dataclass(frozen=True)
class TrackResult:
    """The best pose found and how tracking went."""

    w2c: np.ndarray  # [4, 4] float64, the pose with the lowest evaluated loss
    iterations: int
    converged: bool  # stopped early because the loss stopped improving
    loss: float  # best total loss
    loss_per_pixel: float
    depth_residual_m: float  # mean |D - D_gt| over the loss mask at the best pose
    valid_fraction: float  # fraction of pixels in the loss mask at the best pose
    time_s: float


def track(
    gaussians: GaussianMap,
    frame: FrameTensors,
    init_w2c: np.ndarray,
    s: TrackingSettings,
    render_settings: RenderSettings,
    use_semantics: bool,
) -> TrackResult:
    """Adam on a camera-frame se(3) increment with a fresh optimiser, keeping the best evaluated pose.

    Unlike the reference, the stored best pose is the one that produced the best loss (no
    off-by-one), and tracking stops early once ``stop_patience`` iterations in a row fail to lower
    the best loss by more than ``stop_rel_improvement``.
    """
    t0 = time.perf_counter()
    fixed = gaussians.detach()
    pose = PoseParameters(init_w2c, fixed.device)
    adam = torch.optim.Adam(
        [{"params": [pose.phi], "lr": s.lr_rotation}, {"params": [pose.rho], "lr": s.lr_translation}]
    )
    best = (float("inf"), init_w2c.copy(), 0.0, float("inf"), 0.0)
    stale, converged, it = 0, False, 0
    for it in range(1, s.iterations + 1):
        with record_function("track.render"):
            out = render(fixed, frame.intrinsics, pose.w2c(), render_settings, with_semantics=use_semantics)
        with record_function("track.loss"):
            loss = tracking_loss(out, frame, s, use_semantics)
            value = float(loss.total.detach())
        if loss.mask_fraction == 0:
            break
        stale = 0 if value < best[0] * (1 - s.stop_rel_improvement) else stale + 1
        if value < best[0]:
            best = (value, pose.numpy(), value / (loss.mask_fraction * frame.depth.numel()), loss.depth_residual_m,
                    loss.mask_fraction)  # fmt: skip
        if s.early_stop and it >= s.min_iterations and stale >= s.stop_patience:
            converged = True
            break
        with record_function("track.backward"):
            loss.total.backward()
        with record_function("track.step"):
            adam.step()
            adam.zero_grad(set_to_none=True)
    value, w2c, per_px, residual, fraction = best
    return TrackResult(w2c, it, converged, value, per_px, residual, fraction, time.perf_counter() - t0)
