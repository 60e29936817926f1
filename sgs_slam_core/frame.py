"""The RGB-D(+labels) frame every reader, adapter and node hands to the core."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sgs_slam_core.errors import FrameError
from sgs_slam_core.geometry.camera import Intrinsics

__all__ = ["Frame"]


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
    def valid_depth_fraction(self) -> float:
        """Fraction of pixels with a depth measurement."""
        return float((self.depth > 0).mean())

    @property
    def has_labels(self) -> bool:
        """True when a label image is attached."""
        return self.labels is not None
