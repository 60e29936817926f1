"""Tracking: optimise the camera pose of one frame against the fixed map."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import Tensor

from sgs_slam_core.config.sections import TrackingSettings
from sgs_slam_core.frame_data import FrameTensors
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.kernels.base import Kernels
from sgs_slam_core.kernels.losses import TrackingLoss
from sgs_slam_core.profiling import stage
from sgs_slam_core.render.output import RenderOutput
from sgs_slam_core.slam.adam import FusedAdam
from sgs_slam_core.slam.pose import PoseParameters

__all__ = ["TrackRendering", "TrackResult", "judge_pose", "track"]

# The Adam tracker's early stop (``tracking.adam.early_stop``):
STOP_REL_IMPROVEMENT = 1e-3  # a step "improves" when it lowers the best loss by more than this fraction
STOP_PATIENCE = 5  # steps in a row without improvement that end tracking
# Never stop before this many steps. The patience test cannot stop before step STOP_PATIENCE + 1 anyway,
# so this only bounds how soon live tracking ends when a newer frame waits (``newer_frame_waiting``).
MIN_ITERATIONS = 2
# Read the stop test back from the device every n steps; 0 = every step on the CPU, where reading is
# free, every 5 on CUDA, so the loop does not wait on the GPU.
STOP_CHECK_EVERY = 0


@dataclass(frozen=True)
class TrackRendering:
    """The map as tracking last rendered it, at the result's pose (densification reuses it)."""

    gaussians: GaussianMap  # the map version that was rendered: reusable while it is still the map
    out: RenderOutput


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
    renders: int = 0  # renderings of the map this frame took (0 = as many as iterations)
    rendering: TrackRendering | None = field(default=None, repr=False, compare=False)  # at ``w2c``, if one was
    # The caller's device values read back with the pose (``also_read`` of a tracker's ``track``), or None.
    also_read: np.ndarray | None = field(default=None, repr=False, compare=False)


def track(
    gaussians: GaussianMap,
    frame: FrameTensors,
    init_w2c: np.ndarray,  # [4, 4] float64
    s: TrackingSettings,
    kernels: Kernels,
    use_semantics: bool,
    newer_frame_waiting: Callable[[], bool] | None = None,
) -> TrackResult:
    """Adam on a camera-frame se(3) increment with a fresh optimiser, keeping the best evaluated pose.

    Unlike the reference, the stored best pose is the one that produced the best loss (no
    off-by-one), and tracking stops early once ``STOP_PATIENCE`` iterations in a row fail to lower
    the best loss by more than ``STOP_REL_IMPROVEMENT``. The best pose and the stop counter live on
    the device; the host reads them every ``STOP_CHECK_EVERY`` steps only. Live,
    ``newer_frame_waiting`` (asked at those reads) ends tracking after ``MIN_ITERATIONS`` once it
    returns True: the camera has moved on, and the frame's time is spent.
    """
    t0 = time.perf_counter()
    fixed = gaussians.detach()
    device = fixed.device
    pose = PoseParameters(init_w2c, device)
    adam = FusedAdam({"phi": pose.phi, "rho": pose.rho}, {"phi": s.adam.lr_rotation, "rho": s.adam.lr_translation})
    check_every = STOP_CHECK_EVERY or (5 if device.type == "cuda" else 1)
    best = _Best.start(device)
    converged, it = False, 0
    for it in range(1, s.adam.iterations + 1):
        with stage("track.render"):
            out = kernels.render(fixed, frame.intrinsics, pose.w2c(), with_semantics=use_semantics)
        with stage("track.loss"):
            loss = kernels.tracking_loss(out, frame, s, use_semantics)
            best.update(loss, pose.xi(), STOP_REL_IMPROVEMENT)
        if it % check_every == 0 or it == s.adam.iterations:
            pixels, stale = (int(v) for v in torch.stack([loss.pixels, best.stale]).tolist())  # the one host read
            if pixels == 0:
                break
            if s.adam.early_stop and it >= MIN_ITERATIONS and stale >= STOP_PATIENCE:
                converged = True
                break
            if it >= MIN_ITERATIONS and newer_frame_waiting is not None and newer_frame_waiting():
                break
        with stage("track.backward"):
            loss.total.backward()
        with stage("track.step"):
            adam.step()
    return best.result(pose, init_w2c, it, converged, frame.depth.numel(), t0)


def judge_pose(
    gaussians: GaussianMap,
    frame: FrameTensors,
    w2c: np.ndarray,  # [4, 4] float64
    s: TrackingSettings,
    kernels: Kernels,
    use_semantics: bool,
) -> TrackResult:
    """The tracking loss of ``frame`` at ``w2c`` (one rendering, no step): a pose found elsewhere, judged.

    Any tracker's result carries the same quantities, so the guard judges this pose as it judges a
    tracked one; the rendering goes with it for densification.
    """
    t0 = time.perf_counter()
    fixed = gaussians.detach()
    with stage("track.render"), torch.no_grad():
        pose = torch.as_tensor(w2c, dtype=torch.float32, device=fixed.device)
        out = kernels.render(fixed, frame.intrinsics, pose, with_semantics=use_semantics)
    with stage("track.loss"), torch.no_grad():
        loss = kernels.tracking_loss(out, frame, s, use_semantics)
        stats = torch.stack([loss.total.double(), loss.pixels.double(), loss.depth_residual_m.double()])
    value, pixels, residual = (float(v) for v in stats.tolist())
    elapsed = time.perf_counter() - t0
    if pixels == 0:
        return TrackResult(w2c.copy(), 0, False, float("inf"), 0.0, float("inf"), 0.0, elapsed, 1)
    fraction = pixels / frame.depth.numel()
    return TrackResult(
        w2c.copy(), 0, True, value, value / pixels, residual, fraction, elapsed, 1, TrackRendering(gaussians, out)
    )


@dataclass
class _Best:
    """The lowest loss so far and its pose, on the device; ``stale`` counts steps without real improvement."""

    loss: Tensor  # []
    xi: Tensor  # [6]
    pixels: Tensor  # [] int64
    residual: Tensor  # []
    stale: Tensor  # [] int64

    @staticmethod
    def start(device: torch.device) -> _Best:
        inf = torch.tensor(float("inf"), device=device)
        zero = torch.zeros((), dtype=torch.long, device=device)
        return _Best(inf, torch.zeros(6, device=device), zero, inf.clone(), zero.clone())

    def update(self, loss: TrackingLoss, xi: Tensor, rel_improvement: float) -> None:
        value = loss.total.detach()
        valid = loss.pixels > 0  # an empty mask sums to 0 but explains nothing
        improved = valid & (value < self.loss * (1 - rel_improvement))
        self.stale = torch.where(improved, 0, self.stale + 1)
        better = valid & (value < self.loss)
        self.loss = torch.where(better, value, self.loss)
        self.xi = torch.where(better, xi, self.xi)
        self.pixels = torch.where(better, loss.pixels, self.pixels)
        self.residual = torch.where(better, loss.depth_residual_m, self.residual)

    def result(
        self, pose: PoseParameters, init_w2c: np.ndarray, it: int, converged: bool, num_pixels: int, t0: float
    ) -> TrackResult:
        """The best pose and its loss, read back in one host read; the initial pose if nothing was explained.

        ``t0``: when tracking started (``time.perf_counter()``).
        """
        value, pixels, residual = (
            float(v) for v in torch.stack([self.loss, self.pixels.float(), self.residual]).tolist()
        )
        elapsed = time.perf_counter() - t0
        if pixels == 0:  # no pixel was ever explained: keep the initial pose
            return TrackResult(
                w2c=init_w2c.copy(),
                iterations=it,
                converged=converged,
                loss=float("inf"),
                loss_per_pixel=0.0,
                depth_residual_m=float("inf"),
                valid_fraction=0.0,
                time_s=elapsed,
            )
        return TrackResult(
            w2c=pose.numpy(self.xi),
            iterations=it,
            converged=converged,
            loss=value,
            loss_per_pixel=value / pixels,
            depth_residual_m=residual,
            valid_fraction=pixels / num_pixels,
            time_s=elapsed,
        )
