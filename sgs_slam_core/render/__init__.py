"""Differentiable multi-channel Gaussian renderer: settings, the PyTorch maths, and ``render()`` over the kernels."""

from sgs_slam_core.render.api import CameraGaussians, RenderOutput, render, resolve_backend, to_camera
from sgs_slam_core.render.settings import BackendName, RenderSettings

__all__ = ["BackendName", "CameraGaussians", "RenderOutput", "RenderSettings", "render", "resolve_backend", "to_camera"]
