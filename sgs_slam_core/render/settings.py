"""Renderer settings (the ``render`` section of the SLAM config)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from sgs_slam_core.errors import ConfigError

__all__ = ["INTERNAL", "BackendName", "RenderSettings"]

BackendName = Literal["auto", "torch", "cpu", "gsplat"]
# A settings field marked so (``field(metadata=INTERNAL)``) is no config key: code and tests set it
# where they build the settings object, the config keeps its default.
INTERNAL = {"internal": True}


@dataclass(frozen=True)
class RenderSettings:
    """The ``render`` config section (``backend``) and the constants of the splatting model.

    The model's constants are shared by every backend and are no config keys (the renderer's tests
    and benchmarks vary them where they build the settings).

    Attributes:
        backend: the kernels every render, loss and Gauss-Newton step runs on
            (``kernels/factory.py``): ``torch`` is pure PyTorch on any device (the reference),
            ``cpu`` the compiled kernels (CPU tensors), ``gsplat`` gsplat's rasteriser (CUDA);
            ``auto`` picks gsplat on CUDA when it is installed, ``cpu`` on the CPU when it builds,
            else ``torch``.
        compile: run the Gauss-Newton steps, ICP terms and reference levels, the mapping loss
            (forward and backward) and Adam's update through ``torch.compile``
            (``kernels/compiled.py``): on the ``torch`` and ``gsplat`` backends a step becomes a few
            fused kernels instead of a hundred-odd launches; on ``cpu`` it replaces the backend's own
            C++ ICP, which is faster there (its C++ mapping loss stays). Each new image size
            compiles first (seconds per pyramid level on a GPU host, ten to twenty on two CPU cores):
            ``sgs-slam run`` does it on the first frame before the stream starts, the tracking node
            on the first frame it receives (which it leaves out).
        tile_size: tile side in pixels for the torch backend (8 is fastest on CPU).
        cpu_tile_size: tile side of the compiled cpu backend (4, 8, 16 or 32; capped at the build's
            largest, 32 with AVX-512 float32, else 16); 0 picks 32 (the fastest from 80x60 to
            640x480). Tiling changes the image only by float rounding (pixel offsets from tile corners).
        near_plane: Gaussians with camera-frame z at or below this (m) are culled whole.
        eps2d: isotropic dilation added to every 2D covariance (px^2), as 3DGS/gsplat.
        alpha_max: per-Gaussian alpha clamp (0.99 as the reference rasterizer; gsplat uses 0.999).
        alpha_min: alphas below this are skipped (1/255).
        extent_sigma: footprint cut-off in standard deviations (3).
        min_transmittance: a pixel stops blending at the first Gaussian that would take its
            transmittance below this (1e-4, as the 3DGS/SplaTAM rasterizer); 0 blends everything.
        chunk_elements: pixel x Gaussian pairs evaluated per batch by the torch backend (memory knob).
    """

    backend: BackendName = "auto"
    compile: bool = False
    tile_size: int = field(default=8, metadata=INTERNAL)
    cpu_tile_size: int = field(default=0, metadata=INTERNAL)
    near_plane: float = field(default=0.01, metadata=INTERNAL)
    eps2d: float = field(default=0.3, metadata=INTERNAL)
    alpha_max: float = field(default=0.99, metadata=INTERNAL)
    alpha_min: float = field(default=1.0 / 255.0, metadata=INTERNAL)
    extent_sigma: float = field(default=3.0, metadata=INTERNAL)
    min_transmittance: float = field(default=1e-4, metadata=INTERNAL)
    chunk_elements: int = field(default=1 << 18, metadata=INTERNAL)

    def cpu_tile(self, max_tile: int) -> int:
        """Tile side the compiled cpu backend uses, given the largest its build takes."""
        return min(self.cpu_tile_size or 32, max_tile)

    def __post_init__(self) -> None:
        if self.backend not in ("auto", "torch", "cpu", "gsplat"):
            raise ConfigError(f"render.backend must be auto, torch, cpu or gsplat, got {self.backend!r}")
        if not 1 <= self.tile_size <= 64:
            raise ConfigError(f"RenderSettings.tile_size must be in [1, 64], got {self.tile_size}")
        if self.cpu_tile_size not in (0, 4, 8, 16, 32):
            raise ConfigError(
                f"RenderSettings.cpu_tile_size must be 0 (auto), 4, 8, 16 or 32, got {self.cpu_tile_size}"
            )
        if not self.near_plane > 0:
            raise ConfigError(f"RenderSettings.near_plane must be > 0, got {self.near_plane}")
        if self.eps2d < 0:
            raise ConfigError(f"RenderSettings.eps2d must be >= 0, got {self.eps2d}")
        if not 0 < self.alpha_min < self.alpha_max < 1:
            raise ConfigError(f"need 0 < alpha_min < alpha_max < 1, got {self.alpha_min}, {self.alpha_max}")
        if not 0 < self.extent_sigma <= 10:
            raise ConfigError(f"RenderSettings.extent_sigma must be in (0, 10], got {self.extent_sigma}")
        if not 0 <= self.min_transmittance < 0.5:
            raise ConfigError(f"RenderSettings.min_transmittance must be in [0, 0.5), got {self.min_transmittance}")
        if self.chunk_elements < 1024:
            raise ConfigError(f"RenderSettings.chunk_elements must be >= 1024, got {self.chunk_elements}")
