"""Differentiable multi-channel Gaussian renderer in PyTorch: settings, outputs, projection, tiling, compositing.

``render()`` (in :mod:`sgs_slam_core.kernels`) runs it, or a compiled or CUDA kernel, by ``render.backend``.
"""

from sgs_slam_core.render.output import CameraGaussians, RenderOutput, to_camera
from sgs_slam_core.render.settings import BackendName, RenderSettings

__all__ = ["BackendName", "CameraGaussians", "RenderOutput", "RenderSettings", "to_camera"]
