"""The compiled CPU kernels behind the :class:`~sgs_slam_core.kernels.base.Kernels` interface."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

from torch import Tensor

from sgs_slam_core import native
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.kernels.base import Kernels
from sgs_slam_core.kernels.cpu import losses
from sgs_slam_core.kernels.cpu.extensions import EXTENSIONS
from sgs_slam_core.kernels.cpu.gauss_newton import ICP_KERNELS
from sgs_slam_core.kernels.cpu.mapping_step import mapping_step_grads
from sgs_slam_core.kernels.cpu.render import composite_cpu, render_world_isotropic_cpu
from sgs_slam_core.kernels.reference import project_with_depth
from sgs_slam_core.render.output import RenderOutput, to_camera

if TYPE_CHECKING:
    from sgs_slam_core.config.sections import MappingSettings, TrackingSettings
    from sgs_slam_core.frame_data import FrameTensors
    from sgs_slam_core.gaussians import GaussianMap
    from sgs_slam_core.kernels.losses import TrackingLoss

__all__ = ["CpuKernels"]


class CpuKernels(Kernels):
    """C++ with OpenMP for CPU tensors: rendering, the losses, the direct mapping step, the ICP's parts."""

    name = "cpu"
    icp = ICP_KERNELS

    def prepare(self, announce: Callable[[str], None]) -> None:
        """Build or load the three extensions (about a minute each the first time on a machine)."""
        native.prepare(EXTENSIONS, announce)

    def _render(
        self, gaussians: GaussianMap, intrinsics: Intrinsics, w2c: Tensor, with_semantics: bool
    ) -> RenderOutput:
        k, g = intrinsics, gaussians
        if g.isotropic:  # the map's parameters straight into the kernels
            semantics = g.semantics if with_semantics else g.semantics[:, :0]
            fields = (g.means, g.log_scales, g.logit_opacities, g.colors, semantics)
            images = render_world_isotropic_cpu(*fields, w2c, k, self.settings)
            depth = images.depth.view(k.height, k.width)
            return RenderOutput(images.color, depth, images.silhouette, images.semantic, self.name)
        cam = to_camera(gaussians, w2c, with_semantics)
        proj, feats = project_with_depth(cam, k, self.settings)
        groups = (3, cam.features.shape[1] - 3, 1)  # separate outputs: no slice of an image needs a backward
        splats = (proj.means2d, proj.conics, proj.opacities, feats, proj.radii, proj.depths)
        color, semantic, depth, sil = composite_cpu(*splats, k.width, k.height, self.settings, groups)
        return RenderOutput(color, depth.view(k.height, k.width), sil, semantic, self.name)

    def tracking_loss(
        self, out: RenderOutput, frame: FrameTensors, s: TrackingSettings, use_semantics: bool
    ) -> TrackingLoss:
        """:func:`sgs_slam_core.kernels.cpu.losses.tracking_loss`."""
        return losses.tracking_loss(out, frame, s, use_semantics)

    def mapping_loss(
        self, out: RenderOutput, frame: FrameTensors, s: MappingSettings, use_semantics: bool, scale: float = 1.0
    ) -> Tensor:  # []
        """:func:`sgs_slam_core.kernels.cpu.losses.mapping_loss`."""
        return losses.mapping_loss(out, frame, s, use_semantics, scale)

    def photometric_loss(self, pred: Tensor, target: Tensor, ignore: Tensor | None, ssim_weight: float) -> Tensor:
        """:func:`sgs_slam_core.kernels.cpu.losses.photometric_loss`."""
        return losses.photometric_loss(pred, target, ignore, ssim_weight)

    def direct_mapping(self, isotropic: bool) -> bool:
        """Isotropic maps: their mapping steps need no autograd graph."""
        return isotropic

    def mapping_step_grads(
        self,
        params: dict[str, Tensor],
        data: FrameTensors,
        w2c: Tensor,
        s: MappingSettings,
        semantic: bool,
        weight: float,
        window_semantic: bool = True,
    ) -> Tensor:
        """:func:`sgs_slam_core.kernels.cpu.mapping_step.mapping_step_grads`."""
        return mapping_step_grads(params, data, w2c, s, self.settings, semantic, weight, window_semantic)
