"""Tracking's starting pose: the motion prediction refined by depth ICP against the last tracked frame."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.geometry.icp import IcpKernels, IcpLevel, IcpSettings, align_depth, icp_pyramid
from sgs_slam_core.profiling import stage

__all__ = ["IcpInit", "IcpOutcome"]


@dataclass(frozen=True)
class IcpOutcome:
    """What the ICP did to a frame's starting pose."""

    used: bool  # the refined pose replaced the prediction
    inlier_fraction: float
    rms_m: float


@dataclass
class _Reference:
    depth: Tensor  # [H, W] m, 0 = invalid
    intrinsics: Intrinsics
    c2w: np.ndarray  # [4, 4] float64
    levels: list[IcpLevel] | None = None  # its pyramid, made when first needed


class IcpInit:
    """Keeps the last tracked frame's depth and aligns a new frame's depth to it.

    Used by one tracking thread; ``Slam.reset`` (and so a map load) makes a fresh one.
    """

    def __init__(self, settings: IcpSettings, min_inliers: float, kernels: IcpKernels | None = None) -> None:
        """``kernels``: the ICP's compiled parts (``Kernels.icp``); None = ``geometry.icp``'s PyTorch code."""
        self.settings, self.min_inliers = settings, min_inliers
        self.kernels = kernels or IcpKernels()
        self._reference: _Reference | None = None

    def remember(self, depth: Tensor, intrinsics: Intrinsics, c2w: np.ndarray) -> None:  # depth [H, W] m
        """Make ``depth``, seen from ``c2w``, the reference of the next frame (kept, not copied)."""
        self._reference = _Reference(depth, intrinsics, np.asarray(c2w, dtype=np.float64).copy())

    def refine(
        self, depth: Tensor, intrinsics: Intrinsics, predicted_c2w: np.ndarray
    ) -> tuple[np.ndarray, IcpOutcome | None]:  # depth [H, W] m -> c2w [4, 4]
        """The starting pose for a frame with ``depth``: the ICP result, or else the prediction.

        The prediction is kept when there is no reference (outcome None) or too few pixels found a
        correspondence.
        """
        ref = self._reference
        if ref is None or ref.intrinsics != intrinsics:
            return predicted_c2w, None
        init = torch.as_tensor(np.linalg.inv(ref.c2w) @ predicted_c2w, dtype=torch.float64, device=depth.device)
        with stage("icp"):
            if ref.levels is None:
                levels = len(self.settings.steps_for(intrinsics.width))
                ref.levels = icp_pyramid(ref.depth, ref.intrinsics, levels, self.kernels.level)
            result = align_depth(depth, intrinsics, ref.levels, init, self.settings, self.kernels)
        used = result.inlier_fraction >= self.min_inliers and np.isfinite(result.rms_m)
        outcome = IcpOutcome(used, result.inlier_fraction, result.rms_m)
        if not used:
            return predicted_c2w, outcome
        return ref.c2w @ result.src_to_ref.cpu().numpy(), outcome
