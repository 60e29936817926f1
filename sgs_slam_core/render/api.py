"""``render()``: colour, depth, silhouette and semantic channels of a Gaussian map in one pass.

The Gaussian means (and, for anisotropic maps, covariances) are moved into the camera frame here,
in PyTorch, and the backend rasterises with an identity view. Gradients with respect to ``w2c``
therefore come from autograd on every backend.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import Tensor

from sgs_slam_core.errors import BackendUnavailableError, ShapeError
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.geometry.se3 import quat_multiply, quat_to_rotmat, rotmat_to_quat
from sgs_slam_core.render import cpu_backend, gsplat_backend
from sgs_slam_core.render.composite import composite
from sgs_slam_core.render.projection import project_gaussians
from sgs_slam_core.render.settings import BackendName, RenderSettings
from sgs_slam_core.render.tiling import plan_tiles

__all__ = ["CameraGaussians", "RenderOutput", "render", "resolve_backend", "to_camera"]

log = logging.getLogger(__name__)


@dataclass
class RenderOutput:
    """Rendered channels; all ``[H, W, ...]`` on the map's device."""

    color: Tensor  # [H, W, 3]
    depth: Tensor  # [H, W] sum of w * z (not normalised by the silhouette, as the reference)
    silhouette: Tensor  # [H, W] accumulated alpha in [0, 1]
    semantic: Tensor  # [H, W, S]
    backend: str = "torch"

    def labels(self, decode: Callable[[Tensor], Tensor]) -> Tensor:  # [H, W] int64
        """Class ids per pixel, decoded from ``semantic`` by e.g. ``SemanticCodec.decode``."""
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


def resolve_backend(requested: BackendName, device: torch.device) -> str:
    """The backend that will run.

    ``auto`` means gsplat for CUDA tensors when importable, the compiled backend for CPU tensors
    when it builds (the first call may build it, about a minute), else torch.
    """
    if requested == "torch":
        return "torch"
    if requested == "cpu":
        if device.type != "cpu":
            raise BackendUnavailableError("the compiled cpu backend takes CPU tensors")
        cpu_backend.extension()  # raises with the build error
        return "cpu"
    on_cuda = device.type == "cuda" and torch.cuda.is_available()
    if requested == "gsplat":
        if not on_cuda:
            raise BackendUnavailableError("the gsplat backend needs CUDA tensors and a CUDA device")
        if not gsplat_backend.is_available():
            raise BackendUnavailableError(f"gsplat is not importable: {gsplat_backend.import_error()}")
        return "gsplat"
    if on_cuda:
        return "gsplat" if gsplat_backend.is_available() else "torch"
    if device.type == "cpu" and cpu_backend.is_available():
        return "cpu"
    if device.type == "cpu" and not _warned_fallback:
        _warn_fallback(cpu_backend.unavailable_reason())
    return "torch"


_warned_fallback = False


def _warn_fallback(reason: str) -> None:
    global _warned_fallback  # noqa: PLW0603 - warn once per process
    _warned_fallback = True
    log.warning("render backend auto: %s", reason)


def render(
    gaussians: GaussianMap,
    intrinsics: Intrinsics,
    w2c: Tensor,  # [4, 4] world-to-camera, may require grad
    settings: RenderSettings | None = None,
    with_semantics: bool = True,
) -> RenderOutput:
    """Render every channel of ``gaussians`` seen from ``w2c`` in one pass.

    With ``with_semantics=False`` the semantic channels are skipped (``semantic`` is then ``[H, W, 0]``).
    """
    settings = settings or RenderSettings()
    if tuple(w2c.shape) != (4, 4):
        raise ShapeError(f"w2c must be [4, 4], got {list(w2c.shape)}")
    w2c = w2c.to(device=gaussians.device, dtype=gaussians.means.dtype)
    backend = resolve_backend(settings.backend, gaussians.device)
    if backend == "cpu" and gaussians.isotropic:  # the map's parameters straight into the kernels
        g = gaussians
        semantics = g.semantics if with_semantics else g.semantics[:, :0]
        color, semantic, depth, sil = cpu_backend.render_world_isotropic_cpu(
            g.means, g.log_scales, g.logit_opacities, g.colors, semantics, w2c, intrinsics, settings
        )
        return RenderOutput(color, depth.view(intrinsics.height, intrinsics.width), sil, semantic, backend)
    cam = to_camera(gaussians, w2c, with_semantics)
    if backend == "gsplat":
        feats, depth, sil = gsplat_backend.rasterize(cam, intrinsics, settings)
        color, semantic = feats[..., :3], feats[..., 3:]
    else:
        color, semantic, depth, sil = _rasterize_tiled(cam, intrinsics, settings, compiled=backend == "cpu")
    return RenderOutput(color=color, depth=depth, silhouette=sil, semantic=semantic, backend=backend)


def camera_covariances(cam: CameraGaussians) -> Tensor:  # [N, 3, 3]
    """Camera-frame covariances R S^2 R^T of anisotropic Gaussians."""
    if cam.quats is None:
        raise ShapeError("camera_covariances needs anisotropic Gaussians")
    rot = quat_to_rotmat(cam.quats)  # [N, 3, 3]
    m = rot * cam.scales[:, None, :]
    return m @ m.transpose(1, 2)


def _rasterize_tiled(
    cam: CameraGaussians, intrinsics: Intrinsics, settings: RenderSettings, compiled: bool
) -> tuple[Tensor, Tensor, Tensor, Tensor]:  # colour [H, W, 3], semantic [H, W, S], depth [H, W], sil [H, W]
    """Projection in torch (autograd), then the compiled or the torch compositor.

    (Isotropic maps on the compiled backend do not come here: ``render`` sends them whole to
    :func:`cpu_backend.render_world_isotropic_cpu`.)
    """
    k, d = intrinsics, cam.features.shape[1]
    groups = (3, d - 3)  # colour, semantics: separate outputs, so no slice of the image needs a backward
    if cam.quats is None:
        proj = project_gaussians(cam.means, cam.opacities, intrinsics, settings, scales=cam.scales)
    else:
        covars = camera_covariances(cam)
        proj = project_gaussians(cam.means, cam.opacities, intrinsics, settings, covars_cam=covars)
    feats = torch.cat([cam.features, proj.depths[:, None]], dim=1)
    if compiled:
        color, semantic, depth, sil = cpu_backend.composite_cpu(
            proj.means2d, proj.conics, proj.opacities, feats, proj.radii, proj.depths, k.width, k.height, settings,
            (*groups, 1),
        )  # fmt: skip
        return color, semantic, depth.view(k.height, k.width), sil
    plan = plan_tiles(proj.means2d, proj.radii, proj.depths, k.width, k.height, settings.tile_size,
                      settings.chunk_elements)  # fmt: skip
    img, sil = composite(proj.means2d, proj.conics, proj.opacities, feats, plan, settings)
    return img[..., :3], img[..., 3:-1], img[..., -1], sil
