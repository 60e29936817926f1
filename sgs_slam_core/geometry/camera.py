"""Pinhole intrinsics and back-projection.

Pixel convention (OpenCV): the centre of pixel (u, v) is at image coordinates (u, v), so a
W-pixel-wide image centred on the axis has ``cx = (W - 1) / 2``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from sgs_slam_core.errors import ShapeError

__all__ = ["Intrinsics", "backproject", "pixel_grid", "vertex_map"]


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole camera: focal lengths and principal point in pixels, image size in pixels."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self) -> None:
        values = (self.fx, self.fy, self.cx, self.cy)
        if not all(math.isfinite(v) for v in values):
            raise ShapeError(f"intrinsics must be finite, got {values}")
        if self.fx <= 0 or self.fy <= 0:
            raise ShapeError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        if int(self.width) != self.width or int(self.height) != self.height or self.width < 1 or self.height < 1:
            raise ShapeError(f"image size must be positive integers, got {self.width}x{self.height}")
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width) in pixels."""
        return (self.height, self.width)

    def resized(self, width: int, height: int) -> Intrinsics:
        """Intrinsics of the same camera after resizing the image to ``width`` x ``height``."""
        sx, sy = width / self.width, height / self.height
        return Intrinsics(
            fx=self.fx * sx,
            fy=self.fy * sy,
            cx=(self.cx + 0.5) * sx - 0.5,
            cy=(self.cy + 0.5) * sy - 0.5,
            width=width,
            height=height,
        )

    def scaled(self, factor: float) -> Intrinsics:
        """Intrinsics after scaling the image by ``factor`` (e.g. 0.5 halves each side; sizes rounded)."""
        if not factor > 0:
            raise ShapeError(f"scale factor must be positive, got {factor}")
        return self.resized(max(1, round(self.width * factor)), max(1, round(self.height * factor)))

    def matrix(self) -> np.ndarray:  # [3, 3] float64
        """The 3x3 calibration matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @staticmethod
    def from_matrix(k: np.ndarray, width: int, height: int) -> Intrinsics:
        """Build from a 3x3 (or 4x4) calibration matrix."""
        k = np.asarray(k, dtype=np.float64)
        if k.shape not in ((3, 3), (4, 4)):
            raise ShapeError(f"calibration matrix must be 3x3 or 4x4, got {k.shape}")
        return Intrinsics(float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2]), width, height)


def pixel_grid(height: int, width: int, device: torch.device | str = "cpu") -> tuple[Tensor, Tensor]:
    """Pixel-centre coordinates ``(u [H, W], v [H, W])`` as float32."""
    v, u = torch.meshgrid(
        torch.arange(height, dtype=torch.float32, device=device),
        torch.arange(width, dtype=torch.float32, device=device),
        indexing="ij",
    )
    return u, v


def vertex_map(depth: Tensor, intrinsics: Intrinsics) -> Tensor:  # [H, W] m, 0 = invalid -> [H, W, 3]
    """Camera-frame point of every pixel, 0 where the depth is not finite and positive (fixed shape)."""
    if depth.shape != intrinsics.shape:
        raise ShapeError(f"depth is {tuple(depth.shape)} but intrinsics are {intrinsics.shape}")
    z = torch.where(torch.isfinite(depth) & (depth > 0), depth, 0.0)
    u, v = (t.to(depth.dtype) for t in pixel_grid(intrinsics.height, intrinsics.width, depth.device))
    return torch.stack([(u - intrinsics.cx) / intrinsics.fx * z, (v - intrinsics.cy) / intrinsics.fy * z, z], dim=-1)


def backproject(
    depth: Tensor,  # [H, W] metres, 0 = invalid
    intrinsics: Intrinsics,
    c2w: Tensor | None = None,  # [4, 4]
) -> tuple[Tensor, Tensor]:
    """3D points of every valid pixel: ``(points [M, 3], mask [H, W] bool)``.

    Points are in the camera frame, or in the world frame when ``c2w`` is given. A pixel is valid
    when its depth is finite and positive.
    """
    points = vertex_map(depth, intrinsics)
    mask = points[..., 2] > 0
    points = points[mask]
    if c2w is not None:
        c2w = c2w.to(points)
        points = points @ c2w[:3, :3].T + c2w[:3, 3]
    return points, mask
