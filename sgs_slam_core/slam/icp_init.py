"""Tracking's starting pose: the motion prediction refined by depth ICP against the last tracked frame."""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor

from sgs_slam_core.frame import CompactFrame
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.geometry.icp import IcpKernels, IcpLevel, IcpSettings, align_device, icp_pyramid
from sgs_slam_core.geometry.views import views_near
from sgs_slam_core.profiling import stage
from sgs_slam_core.slam.pose import read_pose

__all__ = ["DeviceStart", "IcpInit", "IcpOutcome", "ReferencePolicy"]


@dataclass(frozen=True)
class IcpOutcome:
    """What the ICP did to a frame's starting pose."""

    used: bool  # the refined pose replaced the prediction
    inlier_fraction: float
    rms_m: float


class DeviceStart(NamedTuple):
    """A starting pose the ICP refined, still on the device: the tracker reads it back with its own result."""

    c2w: Tensor  # [4, 4] float64: the ICP's pose, or the prediction where it was not used
    outcome: Tensor  # [3] float64: used (1 or 0), inlier fraction, rms (m); for :meth:`IcpInit.settle`


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

    def start(self, depth: Tensor, intrinsics: Intrinsics, predicted_c2w: np.ndarray) -> DeviceStart | None:
        """As :meth:`refine`, without reading the result back; None where there is no reference.

        The caller hands the outcome, once read, to :meth:`settle`.
        """
        ref = self._reference
        if ref is None or ref.intrinsics != intrinsics:
            return None
        return DeviceStart(*self._align_device(ref, depth, intrinsics, predicted_c2w))

    def settle(self, used: bool) -> None:
        """What :meth:`start`'s outcome said: whether the ICP's pose was used (else the reference is replaced)."""
        self._reference_failed = not used

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
        """The start and what the ICP did, in one host read."""
        c2w, outcome = read_pose(*self._align_device(ref, depth, intrinsics, predicted_c2w))
        used, fraction, rms = (float(v) for v in outcome)
        return c2w, IcpOutcome(used > 0, fraction, rms)

    def _align_device(
        self, ref: _Reference, depth: Tensor, intrinsics: Intrinsics, predicted_c2w: np.ndarray
    ) -> tuple[Tensor, Tensor]:  # c2w [4, 4] float64, outcome [3] float64 (used, inlier fraction, rms m)
        """The ICP's pose where enough of the frame's depth found a correspondence, else the prediction."""
        device = depth.device
        init = torch.as_tensor(np.linalg.inv(ref.c2w) @ predicted_c2w, dtype=torch.float64, device=device)
        with stage("icp"):
            if ref.levels is None:
                levels = len(self.settings.steps_for(intrinsics.width))
                ref.levels = icp_pyramid(ref.depth, ref.intrinsics, levels, self.kernels.level)
            result = align_device(depth, intrinsics, ref.levels, init, self.settings, kernels=self.kernels)
        fraction = result.inliers / result.valid_source.clamp_min(1.0)
        found = result.inliers > 0
        rms = torch.where(found, torch.sqrt(result.sum_sq_m2 / result.inliers.clamp_min(1.0)), torch.inf)
        used = (fraction >= self.min_inliers) & torch.isfinite(rms)
        ref_c2w = torch.as_tensor(ref.c2w, dtype=torch.float64, device=device)
        predicted = torch.as_tensor(predicted_c2w, dtype=torch.float64, device=device)
        c2w = torch.where(used, ref_c2w @ result.src_to_ref, predicted)
        return c2w, torch.stack([used.double(), fraction, rms])
