"""What a render returns, and the map moved into the camera frame for a backend."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import Tensor

from sgs_slam_core.errors import ShapeError
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.geometry.se3 import quat_multiply, quat_to_rotmat, rotmat_to_quat

__all__ = ["CameraGaussians", "RenderOutput", "camera_covariances", "to_camera"]


@dataclass
class RenderOutput:
    """Rendered channels; all ``[H, W, ...]`` on the map's device."""

    color: Tensor  # [H, W, 3]
    depth: Tensor  # [H, W] sum of w * z (not normalised by the silhouette, as the reference)
    silhouette: Tensor  # [H, W] accumulated alpha in [0, 1]
    semantic: Tensor  # [H, W, S]
    backend: str = "torch"

    def labels(self, decode: Callable[[Tensor], Tensor]) -> Tensor:  # [H, W] int64
        """Class ids per pixel, decoded from ``semantic`` by e.g. ``SemanticCodec.decode_image``."""
        return decode(self.semantic)


@dataclass
class CameraGaussians:
    """Gaussians expressed in the camera frame, ready for a backend."""

    means: Tensor  # [N, 3]
    scales: Tensor  # [N] (isotropic) or [N, 3]
    quats: Tensor | None  # [N, 4] wxyz, camera frame (anisotropic maps) or None
    opacities: Tensor  # [N]
    features: Tensor  # [N, 3 + S] colour then semantics


def to_camera(gaussians: GaussianMap, w2c: Tensor, with_semantics: bool = True) -> CameraGaussians:
    """Move the map into the camera frame (differentiable with respect to ``w2c``)."""
    rot, trans = w2c[:3, :3], w2c[:3, 3]
    means = gaussians.means @ rot.transpose(0, 1) + trans
    quats = None
    if gaussians.quats is not None:
        quats = quat_multiply(rotmat_to_quat(rot)[None], gaussians.quats)
    feats = [gaussians.colors]
    if with_semantics and gaussians.num_semantic:
        feats.append(gaussians.semantics)
    scales = torch.exp(gaussians.log_scales)
    return CameraGaussians(
        means=means,
        scales=scales[:, 0] if gaussians.isotropic else scales,
        quats=quats,
        opacities=torch.sigmoid(gaussians.logit_opacities),
        features=torch.cat(feats, dim=1),
    )


def camera_covariances(cam: CameraGaussians) -> Tensor:  # [N, 3, 3]
    """Camera-frame covariances R S^2 R^T of anisotropic Gaussians."""
    if cam.quats is None:
        raise ShapeError("camera_covariances needs anisotropic Gaussians")
    rot = quat_to_rotmat(cam.quats)  # [N, 3, 3]
    m = rot * cam.scales[:, None, :]
    return m @ m.transpose(1, 2)
