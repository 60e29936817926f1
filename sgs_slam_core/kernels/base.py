"""The device kernels' interface: rendering, the SLAM's losses and the ICP's parts.

One :class:`Kernels` object per (render settings, device), built by :func:`sgs_slam_core.kernels.build_kernels`,
runs every heavy per-frame operation. Three implementations: the pure-PyTorch reference
(``reference.py``), the compiled CPU kernels (``cpu/``) and gsplat on CUDA (``gsplat.py``). The
optimiser step (:mod:`sgs_slam_core.slam.adam`) is the same fused PyTorch kernel on every device, or
with ``render.compile`` :mod:`sgs_slam_core.kernels.adam`'s update compiled (``Kernels.mapping``).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch
from torch import Tensor

from sgs_slam_core.errors import BackendUnavailableError, ShapeError
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.geometry.icp import IcpKernels
from sgs_slam_core.render.settings import RenderSettings

if TYPE_CHECKING:
    from sgs_slam_core.config.sections import MappingSettings, TrackingSettings
    from sgs_slam_core.frame_data import FrameTensors
    from sgs_slam_core.gaussians import GaussianMap
    from sgs_slam_core.kernels.losses import MappingWeights, MeasuredImages, TrackingLoss
    from sgs_slam_core.kernels.photometric import SsimBlur
    from sgs_slam_core.render.output import RenderOutput

__all__ = ["AdamUpdate", "IcpKernels", "Kernels", "MappingKernels"]

# kernels.losses.mapping_loss_of's signature: rendered colour, depth, semantics, target, weights, SSIM window
MappingLossOf = Callable[["Tensor", "Tensor", "Tensor", "MeasuredImages", "MappingWeights", "SsimBlur"], "Tensor"]

# kernels.adam.adam_update's: parameter, gradient, first and second moments, step count, learning rate, eps
AdamUpdate = Callable[["Tensor", "Tensor", "Tensor", "Tensor", "Tensor", float, float], None]


@dataclass(frozen=True)
class MappingKernels:
    """Compiled forms of a mapping step's PyTorch parts; None where that code runs as written.

    Attributes:
        loss: :func:`~sgs_slam_core.kernels.losses.mapping_loss_of`, its backward compiled with it.
        update: :func:`~sgs_slam_core.kernels.adam.adam_update`, a field's Adam step.
    """

    loss: MappingLossOf | None = None
    update: AdamUpdate | None = None


class Kernels(ABC):
    """The kernels of one backend for one device and one set of render settings.

    Attributes:
        name: ``torch`` (the pure-PyTorch reference), ``cpu`` (compiled) or ``gsplat`` (CUDA).
        settings: the splatting constants every render uses.
        icp: compiled forms of ``geometry.icp``'s step terms, a level's steps, the joint step with
            observations and a reference level (None where its PyTorch code runs).
        mapping: compiled forms of the mapping step's parts (the loss where the backend's is PyTorch's,
            the update on any backend).
    """

    name: str
    icp: IcpKernels = IcpKernels()
    mapping: MappingKernels = MappingKernels()

    def __init__(self, settings: RenderSettings, device: torch.device) -> None:
        self.settings, self.device = settings, device

    def prepare(self, announce: Callable[[str], None]) -> None:  # noqa: B027 - nothing to build by default
        """Build or load whatever these kernels compile, before anything is timed (a line per build)."""

    def render(
        self,
        gaussians: GaussianMap,
        intrinsics: Intrinsics,
        w2c: Tensor,  # [4, 4] world-to-camera, may require grad
        with_semantics: bool = True,
    ) -> RenderOutput:
        """Every channel of ``gaussians`` seen from ``w2c`` in one pass (``semantic`` is ``[H, W, 0]`` without)."""
        if tuple(w2c.shape) != (4, 4):
            raise ShapeError(f"w2c must be [4, 4], got {list(w2c.shape)}")
        w2c = w2c.to(device=gaussians.device, dtype=gaussians.means.dtype)
        return self._render(gaussians, intrinsics, w2c, with_semantics)

    @abstractmethod
    def _render(
        self, gaussians: GaussianMap, intrinsics: Intrinsics, w2c: Tensor, with_semantics: bool
    ) -> RenderOutput:
        """:meth:`render` once ``w2c`` is checked and on the map's device and dtype."""

    @abstractmethod
    def tracking_loss(
        self, out: RenderOutput, frame: FrameTensors, s: TrackingSettings, use_semantics: bool
    ) -> TrackingLoss:
        """Tracking's masked L1 sums (``slam.losses.tracking_loss_reference``), differentiable."""

    @abstractmethod
    def mapping_loss(
        self, out: RenderOutput, frame: FrameTensors, s: MappingSettings, use_semantics: bool, scale: float = 1.0
    ) -> Tensor:  # [] differentiable
        """``scale`` x ``slam.losses.mapping_loss_reference``."""

    @abstractmethod
    def photometric_loss(
        self,
        pred: Tensor,  # [H, W, C] rendered, differentiable
        target: Tensor,  # [H, W, C] measured
        ignore: Tensor | None,  # [H, W] bool: pixels that count as matched
        ssim_weight: float,
    ) -> Tensor:  # []
        """``(1 - w) mean|pred - target| + w (1 - mean SSIM(pred, target))`` (``slam.photometric``)."""

    def direct_mapping(self, isotropic: bool) -> bool:
        """True where :meth:`mapping_step_grads` runs (a map's gradients without autograd)."""
        return False

    def mapping_step_grads(
        self,
        params: dict[str, Tensor],  # the optimiser's leaves: means [N, 3], log_scales [N, 1], ... semantics [N, S]
        data: FrameTensors,
        w2c: Tensor,  # [4, 4] on the map's device
        s: MappingSettings,
        semantic: bool,
        weight: float,
        window_semantic: bool = True,
    ) -> Tensor:  # [] the loss
        """Set each parameter's ``.grad`` as ``render`` + ``mapping_loss`` + ``backward()`` would."""
        raise BackendUnavailableError(f"the {self.name} kernels have no direct mapping step")
