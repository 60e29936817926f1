"""The one place that chooses the kernels: from ``render.backend`` and the tensors' device.

``torch`` is the pure-PyTorch reference everywhere (rendering, losses, SSIM, Gauss-Newton steps);
``cpu`` the compiled kernels (CPU tensors); ``gsplat`` gsplat's rasteriser (CUDA tensors); ``auto``
picks gsplat on CUDA when it imports, the compiled kernels on the CPU when they build (the first
call may build them, about a minute each), else the reference with a warning. ``render.compile``
runs the ICP's parts and Adam's update (any backend) and the mapping loss (the PyTorch backends) through
``torch.compile``.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

import torch

from sgs_slam_core import native
from sgs_slam_core.errors import BackendUnavailableError
from sgs_slam_core.kernels import gsplat
from sgs_slam_core.kernels.base import Kernels
from sgs_slam_core.kernels.compiled import compiled_icp_kernels, compiled_mapping_kernels
from sgs_slam_core.kernels.cpu.extensions import EXTENSIONS
from sgs_slam_core.kernels.cpu.kernels import CpuKernels
from sgs_slam_core.kernels.gsplat import GsplatKernels
from sgs_slam_core.kernels.reference import ReferenceKernels
from sgs_slam_core.render.settings import BackendName, RenderSettings

__all__ = ["build_kernels", "resolve_backend"]

log = logging.getLogger(__name__)

_CACHE: dict[tuple[RenderSettings, torch.device], Kernels] = {}
_LOCK = threading.Lock()  # the ROS nodes' threads may ask at once
_warned_fallback = False


def build_kernels(
    settings: RenderSettings, device: torch.device | str, announce: Callable[[str], None] | None = None
) -> Kernels:
    """The kernels ``settings.backend`` names for tensors on ``device``, built once per (settings, device).

    ``announce`` (default: a logged warning) gets a line for each compiled kernel that has to be
    built first. Raises :class:`BackendUnavailableError` when a named backend cannot run there.
    """
    device = torch.device(device)
    key = (settings, device)
    kernels = _CACHE.get(key)
    if kernels is None:
        with _LOCK:
            kernels = _CACHE.get(key) or _build(settings, device, announce or log.warning)
            _CACHE[key] = kernels
    return kernels


def _build(settings: RenderSettings, device: torch.device, announce: Callable[[str], None]) -> Kernels:
    name = resolve_backend(settings.backend, device, announce)
    if name == "cpu":
        kernels: Kernels = CpuKernels(settings, device)
    elif name == "gsplat":
        kernels = GsplatKernels(settings, device)
    else:
        kernels = ReferenceKernels(settings, device, ssim_blur="band" if device.type == "cpu" else "conv")
    if settings.compile:
        kernels.icp = compiled_icp_kernels(announce)
        kernels.mapping = compiled_mapping_kernels(announce)
    return kernels


def resolve_backend(requested: BackendName, device: torch.device, announce: Callable[[str], None] | None = None) -> str:
    """The name of the kernels that will run: ``torch``, ``cpu`` or ``gsplat`` (may build the CPU kernels)."""
    if requested in ("cpu", "auto") and device.type == "cpu":
        native.prepare(EXTENSIONS, announce or log.warning)
    if requested == "auto":
        return _resolve_auto(device)
    if requested == "cpu":
        if device.type != "cpu":
            raise BackendUnavailableError("the compiled cpu backend takes CPU tensors")
        for ext in EXTENSIONS:
            ext.module()  # raises with the build error
    if requested == "gsplat":
        if not _on_cuda(device):
            raise BackendUnavailableError("the gsplat backend needs CUDA tensors and a CUDA device")
        if not gsplat.is_available():
            raise BackendUnavailableError(f"gsplat is not importable: {gsplat.import_error()}")
    return requested


def _on_cuda(device: torch.device) -> bool:
    return device.type == "cuda" and torch.cuda.is_available()


def _resolve_auto(device: torch.device) -> str:
    """The ``auto`` choice: gsplat on CUDA when it imports, the compiled kernels on the CPU when they build."""
    if _on_cuda(device):
        return "gsplat" if gsplat.is_available() else "torch"
    if device.type != "cpu":
        return "torch"
    unavailable = [ext.unavailable_reason() for ext in EXTENSIONS if not ext.is_available()]
    if not unavailable:
        return "cpu"
    _warn_fallback(unavailable[0])
    return "torch"


def _warn_fallback(reason: str) -> None:
    global _warned_fallback  # noqa: PLW0603 - warn once per process
    if not _warned_fallback:
        _warned_fallback = True
        log.warning("render backend auto: %s", reason)
