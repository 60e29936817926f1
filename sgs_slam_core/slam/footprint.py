"""What a running SLAM holds in memory: Gaussians and keyframes, counted and in bytes."""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from sgs_slam_core.slam.system import Slam

__all__ = ["Footprint", "footprint"]


@dataclass(frozen=True)
class Footprint:
    """The map's and the keyframe store's size now (bytes of tensors and images, not of the process)."""

    gaussians: int
    gaussian_bytes: int  # every field of every Gaussian, on the map's device
    keyframes: int  # held with their images
    keyframe_bytes: int  # host bytes of the held keyframes' images
    keyframes_evicted: int  # let go by the store's cap so far

    def as_metrics(self) -> dict[str, float]:
        """Plain numbers for metrics.json and benchmarks."""
        return {
            "num_gaussians": self.gaussians,
            "gaussian_mb": round(self.gaussian_bytes / 2**20, 2),
            "keyframes": self.keyframes,
            "keyframe_mb": round(self.keyframe_bytes / 2**20, 2),
            "keyframes_evicted": self.keyframes_evicted,
        }

    def as_strings(self) -> dict[str, str]:
        """Key/value strings for a diagnostics status."""
        return {
            "gaussians": str(self.gaussians),
            "gaussian_mb": f"{self.gaussian_bytes / 2**20:.1f}",
            "keyframes": str(self.keyframes),
            "keyframe_mb": f"{self.keyframe_bytes / 2**20:.1f}",
            "keyframes_evicted": str(self.keyframes_evicted),
        }

    def summary(self) -> str:
        """Short text for a progress bar: ``12,345 Gaussians (1.2 MB), 40 keyframes (73 MB)``."""
        return (
            f"{self.gaussians:,} Gaussians ({self.gaussian_bytes / 2**20:.1f} MB), "
            f"{self.keyframes} keyframes ({self.keyframe_bytes / 2**20:.0f} MB)"
        )


def footprint(slam: Slam) -> Footprint:
    """Read the footprint of ``slam`` (the map it holds now: one reference, no copy)."""
    g = slam.gaussians
    tensors = (getattr(g, f.name) for f in fields(g))
    gaussian_bytes = sum(t.numel() * t.element_size() for t in tensors if t is not None)
    store = slam.keyframes.stats()
    return Footprint(len(g), gaussian_bytes, store.held, store.nbytes, store.evicted)
