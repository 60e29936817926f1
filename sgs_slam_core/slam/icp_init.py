"""Tracking's starting pose: the motion prediction refined by depth ICP against the last tracked frame."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from sgs_slam_core.frame import CompactFrame
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.geometry.icp import IcpKernels, IcpLevel, IcpSettings, align_depth, icp_pyramid
from sgs_slam_core.geometry.views import views_near
from sgs_slam_core.profiling import stage

__all__ = ["IcpInit", "IcpOutcome", "ReferencePolicy"]


@dataclass(frozen=True)
class IcpOutcome:
    """What the ICP did to a frame's starting pose."""

    used: bool  # the refined pose replaced the prediction
    inlier_fraction: float
    rms_m: float


@dataclass(frozen=True)
class ReferencePolicy:
    """How long a tracked frame stays the ICP's reference (either 0: one frame).

    Until the camera centre is ``distance_m`` (m) from the reference's or its optical axis turned
    ``angle_deg`` (degrees) from it.
    """

    distance_m: float = 0.0
    angle_deg: float = 0.0

    def keeps(self, ref_c2w: np.ndarray, c2w: np.ndarray) -> bool:  # [4, 4] each
        """Whether the reference taken at ``ref_c2w`` still serves a frame at ``c2w``."""
        if self.distance_m == 0 or self.angle_deg == 0:  # one frame, even where the camera stands still
            return False
        return bool(views_near(ref_c2w[None, :3, 3], ref_c2w[None, :3, 2], c2w, self.distance_m, self.angle_deg)[0])


@dataclass
class _Reference:
    depth: Tensor  # [H, W] m, 0 = invalid
    intrinsics: Intrinsics
    c2w: np.ndarray  # [4, 4] float64
    levels: list[IcpLevel] | None = None  # its pyramid, made when first needed


class IcpInit:
    """Keeps a tracked frame's depth as the reference and aligns a new frame's depth to it.

    Used by one tracking thread; ``Slam.reset`` (and so a map load) makes a fresh one.
    """

    def __init__(
        self,
        settings: IcpSettings,
        min_inliers: float,
        kernels: IcpKernels | None = None,
        policy: ReferencePolicy | None = None,
    ) -> None:
        """``kernels``: the ICP's compiled parts (``Kernels.icp``); None = ``geometry.icp``'s PyTorch code.

        ``policy``: how long a reference is kept (None: every tracked frame replaces it).
        """
        self.settings, self.min_inliers = settings, min_inliers
        self.kernels = kernels or IcpKernels()
        self.policy = policy or ReferencePolicy()
        self._reference: _Reference | None = None
        self._reference_failed = False  # the last alignment against the reference was not used

    @property
    def reference_c2w(self) -> np.ndarray | None:  # [4, 4]
        """Where the current reference frame was taken; None before the first."""
        return None if self._reference is None else self._reference.c2w.copy()

    def remember(self, depth: Tensor, intrinsics: Intrinsics, c2w: np.ndarray) -> None:  # depth [H, W] m
        """Make a tracked frame's ``depth``, seen from ``c2w`` [4, 4], the reference (kept, not copied).

        Unless the current reference still serves that pose (``policy``) and the last alignment
        against it succeeded.
        """
        c2w = np.asarray(c2w, dtype=np.float64)
        ref = self._reference
        if (
            ref is not None
            and ref.intrinsics == intrinsics
            and not self._reference_failed
            and self.policy.keeps(ref.c2w, c2w)
        ):
            return
        self._reference = _Reference(depth, intrinsics, c2w.copy())
        self._reference_failed = False

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
        c2w, outcome = self._align(ref, depth, intrinsics, predicted_c2w)
        self._reference_failed = not outcome.used
        return c2w, outcome

    def refine_against(
        self, reference: CompactFrame, depth: Tensor, intrinsics: Intrinsics, predicted_c2w: np.ndarray
    ) -> tuple[np.ndarray, IcpOutcome | None]:  # depth [H, W] m -> c2w [4, 4]
        """As :meth:`refine`, against a stored keyframe instead of the kept reference (which stays)."""
        if reference.intrinsics != intrinsics:
            return predicted_c2w, None
        ref_depth = torch.as_tensor(reference.depth_m, device=depth.device)
        return self._align(
            _Reference(ref_depth, intrinsics, np.linalg.inv(reference.w2c)), depth, intrinsics, predicted_c2w
        )

    def _align(
        self, ref: _Reference, depth: Tensor, intrinsics: Intrinsics, predicted_c2w: np.ndarray
    ) -> tuple[np.ndarray, IcpOutcome]:
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
        return ref.c2w @ result.src_to_ref.numpy(), outcome
