"""The pure-PyTorch kernels: the reference every compiled path is tested against, on any device.

Rendering projects and composites tile by tile in PyTorch (``render/projection.py``,
``render/tiling.py``, ``render/composite.py``) with autograd for every gradient; the losses are
:mod:`sgs_slam_core.kernels.losses`' definitions; the Gauss-Newton tracker takes ``geometry.icp``'s
PyTorch steps.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch
from torch import Tensor

from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.kernels.base import Kernels
from sgs_slam_core.kernels.losses import TrackingLoss, mapping_inputs, mapping_loss_of, tracking_loss_reference
from sgs_slam_core.kernels.photometric import SsimBlur, photometric_loss
from sgs_slam_core.render.composite import composite
from sgs_slam_core.render.output import CameraGaussians, RenderOutput, camera_covariances, to_camera
from sgs_slam_core.render.projection import Projection, project_gaussians
from sgs_slam_core.render.settings import RenderSettings
from sgs_slam_core.render.tiling import plan_tiles

if TYPE_CHECKING:
    from sgs_slam_core.config.sections import MappingSettings, TrackingSettings
    from sgs_slam_core.frame_data import FrameTensors
    from sgs_slam_core.gaussians import GaussianMap

__all__ = ["ReferenceKernels", "project_with_depth"]


def project_with_depth(
    cam: CameraGaussians, intrinsics: Intrinsics, settings: RenderSettings
) -> tuple[Projection, Tensor]:  # the projection, features then depth [N, D + 1]
    """The camera-frame Gaussians projected (autograd), and their features with the depth appended."""
    if cam.quats is None:
        proj = project_gaussians(cam.means, cam.opacities, intrinsics, settings, scales=cam.scales)
    else:
        covars = camera_covariances(cam)
        proj = project_gaussians(cam.means, cam.opacities, intrinsics, settings, covars_cam=covars)
    return proj, torch.cat([cam.features, proj.depths[:, None]], dim=1)


class ReferenceKernels(Kernels):
    """Pure PyTorch throughout; ``ssim_blur`` is the SSIM window's form (``band`` on the CPU, ``conv`` elsewhere)."""

    name = "torch"

    def __init__(self, settings: RenderSettings, device: torch.device, ssim_blur: SsimBlur = "band") -> None:
        super().__init__(settings, device)
        self.ssim_blur: SsimBlur = ssim_blur

    def _render(
        self, gaussians: GaussianMap, intrinsics: Intrinsics, w2c: Tensor, with_semantics: bool
    ) -> RenderOutput:
        cam = to_camera(gaussians, w2c, with_semantics)
        proj, feats = project_with_depth(cam, intrinsics, self.settings)
        plan = plan_tiles(
            proj.means2d,
            proj.radii,
            proj.depths,
            intrinsics.width,
            intrinsics.height,
            self.settings.tile_size,
            self.settings.chunk_elements,
        )
        img, sil = composite(proj.means2d, proj.conics, proj.opacities, feats, plan, self.settings)
        return RenderOutput(
            color=img[..., :3], depth=img[..., -1], silhouette=sil, semantic=img[..., 3:-1], backend=self.name
        )

    def tracking_loss(
        self, out: RenderOutput, frame: FrameTensors, s: TrackingSettings, use_semantics: bool
    ) -> TrackingLoss:
        """:func:`sgs_slam_core.kernels.losses.tracking_loss_reference`."""
        return tracking_loss_reference(out, frame, s, use_semantics)

    def mapping_loss(
        self, out: RenderOutput, frame: FrameTensors, s: MappingSettings, use_semantics: bool, scale: float = 1.0
    ) -> Tensor:  # []
        """``scale`` x :func:`sgs_slam_core.kernels.losses.mapping_loss_reference` (compiled in ``mapping.loss``)."""
        target, weights = mapping_inputs(frame, s, use_semantics)
        loss_of = self.mapping.loss or mapping_loss_of
        return scale * loss_of(out.color, out.depth, out.semantic, target, weights, self.ssim_blur)

    def photometric_loss(self, pred: Tensor, target: Tensor, ignore: Tensor | None, ssim_weight: float) -> Tensor:
        """:func:`sgs_slam_core.kernels.photometric.photometric_loss` with this device's SSIM window."""
        return photometric_loss(pred, target, ignore, ssim_weight, self.ssim_blur)
