"""The RGB-D(+labels) frame every reader, adapter and node hands to the core, and its compact stored form."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sgs_slam_core.errors import FrameError
from sgs_slam_core.geometry.camera import Intrinsics

__all__ = ["DEPTH_UNITS_PER_M", "CompactFrame", "Frame", "compact_labels"]

DEPTH_UNITS_PER_M = 5000.0  # compact depth: uint16 in 0.2 mm steps, up to 13.1 m


@dataclass(frozen=True)
class Frame:
    """One synchronised observation.

    Depth is in metres with 0 meaning "no measurement"; labels are class ids with 0 meaning
    "unlabelled". ``gt_c2w`` is the ground-truth camera-to-world pose (optical frame) when known.
    """

    rgb: np.ndarray  # [H, W, 3] uint8
    depth: np.ndarray  # [H, W] float32 metres, 0 = invalid
    intrinsics: Intrinsics
    labels: np.ndarray | None = None  # [H, W] int32 class ids, 0 = unlabelled
    stamp_ns: int = 0
    gt_c2w: np.ndarray | None = None  # [4, 4] float64
    index: int = 0

    def __post_init__(self) -> None:
        h, w = self.intrinsics.shape
        if self.rgb.shape != (h, w, 3) or self.rgb.dtype != np.uint8:
            raise FrameError(
                f"rgb must be uint8 [{h}, {w}, 3] for these intrinsics, got {self.rgb.dtype} {self.rgb.shape}"
            )
        if self.depth.shape != (h, w):
            raise FrameError(f"depth must be [{h}, {w}] like the colour image, got {self.depth.shape}")
        if self.depth.dtype != np.float32:
            raise FrameError(f"depth must be float32 metres, got {self.depth.dtype}")
        if not np.isfinite(self.depth).all():
            raise FrameError("depth contains NaN or inf; use 0 for invalid pixels")
        if (self.depth < 0).any():
            raise FrameError("depth contains negative values")
        if self.labels is not None:
            if self.labels.shape != (h, w):
                raise FrameError(f"labels must be [{h}, {w}] like the colour image, got {self.labels.shape}")
            if not np.issubdtype(self.labels.dtype, np.integer):
                raise FrameError(f"labels must be integer class ids, got {self.labels.dtype}")
            if self.labels.size and self.labels.min() < 0:
                raise FrameError("labels contain negative class ids")
        if self.gt_c2w is not None:
            if self.gt_c2w.shape != (4, 4):
                raise FrameError(f"gt_c2w must be 4x4, got {self.gt_c2w.shape}")
            if not np.isfinite(self.gt_c2w).all():
                raise FrameError("gt_c2w is not finite; pass None for frames without ground truth")

    @property
    def nbytes(self) -> int:
        """Host memory held by this frame's images (bytes)."""
        return self.rgb.nbytes + self.depth.nbytes + (self.labels.nbytes if self.labels is not None else 0)

    @property
    def valid_depth_fraction(self) -> float:
        """Fraction of pixels with a depth measurement."""
        return float((self.depth > 0).mean())

    @property
    def has_labels(self) -> bool:
        """True when a label image is attached."""
        return self.labels is not None


def compact_labels(labels: np.ndarray) -> np.ndarray:  # [H, W] uint8, uint16 or int32
    """Class ids in the smallest integer type that holds them (uint8 for NYU40 or Replica ids)."""
    if labels.size == 0 or (labels.min() >= 0 and labels.max() < 2**8):
        return labels.astype(np.uint8)
    if labels.min() >= 0 and labels.max() < 2**16:
        return labels.astype(np.uint16)
    return labels.astype(np.int32)


@dataclass
class CompactFrame:
    """A keyframe kept on the host: uint8 colour, uint16 depth (0.2 mm), compact labels, its pose."""

    index: int
    stamp_ns: int
    intrinsics: Intrinsics
    rgb: np.ndarray  # [H, W, 3] uint8
    depth: np.ndarray  # [H, W] uint16, DEPTH_UNITS_PER_M per metre
    labels: np.ndarray | None  # [H, W] uint8 (ids < 256), uint16 (< 65536) or int32
    w2c: np.ndarray  # [4, 4] float64, the estimate at insertion (not refined later, as the reference)

    @staticmethod
    def from_frame(frame: Frame, w2c: np.ndarray) -> CompactFrame:
        """Compress a frame (depth beyond 13.1 m becomes invalid)."""
        units = np.round(frame.depth * DEPTH_UNITS_PER_M)
        depth = np.where(units <= 65535, units, 0).astype(np.uint16)
        return CompactFrame(
            frame.index,
            frame.stamp_ns,
            frame.intrinsics,
            frame.rgb.copy(),
            depth,
            None if frame.labels is None else compact_labels(frame.labels),
            w2c.copy(),
        )

    @property
    def depth_m(self) -> np.ndarray:  # [H, W] float32
        """Depth in metres."""
        return self.depth.astype(np.float32) / np.float32(DEPTH_UNITS_PER_M)

    @property
    def nbytes(self) -> int:
        """Host memory held by this keyframe."""
        return self.rgb.nbytes + self.depth.nbytes + (self.labels.nbytes if self.labels is not None else 0)
