"""The device kernels, chosen once per configuration and device (:func:`build_kernels`), and ``render()`` over them."""

from sgs_slam_core.kernels.api import render
from sgs_slam_core.kernels.base import IcpKernels, Kernels
from sgs_slam_core.kernels.factory import build_kernels, resolve_backend

__all__ = ["IcpKernels", "Kernels", "build_kernels", "render", "resolve_backend"]
