"""The axial noise of a depth camera, and the weights it gives point-to-plane residuals.

A structured-light or stereo camera measures depth with an error that grows with about the square
of the depth: a Kinect measures a point at 3 m about seven times less precisely than one at 1 m.
Weighting each residual by the inverse of its noise lets the near surfaces, which the camera
measures well, decide the pose instead of the far background's noise.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TypeVar

import numpy as np
import torch
from torch import Tensor

from sgs_slam_core.errors import ConfigError

__all__ = ["DepthNoise"]

_NO_DEPTH_UNIT_M = 1.0  # the unit depth of an image without a valid depth (none of its weights is used)

_Depth = TypeVar("_Depth", float, np.ndarray, Tensor)


@dataclass(frozen=True)
class DepthNoise:
    """Axial noise ``sigma(z) = base_m + quadratic_per_m * (z - offset_m)^2`` (m) of a depth camera.

    The defaults are Nguyen, Izadi and Lovell's fit for the Kinect v1 ("Modeling Kinect Sensor
    Noise for Improved 3D Reconstruction and Tracking", 3DIMPVT 2012): 1.9 mm at 1 m, 14 mm at 3 m.

    Attributes:
        base_m: the noise at ``offset_m`` (m), > 0.
        quadratic_per_m: growth with the squared distance from ``offset_m`` (1/m), >= 0.
        offset_m: the depth of least noise (m), >= 0.
    """

    base_m: float = 0.0012
    quadratic_per_m: float = 0.0019
    offset_m: float = 0.4

    def __post_init__(self) -> None:
        if not self.base_m > 0:
            raise ConfigError(f"depth noise base_m must be > 0, got {self.base_m}")
        if self.quadratic_per_m < 0 or self.offset_m < 0:
            raise ConfigError(
                f"depth noise quadratic_per_m and offset_m must be >= 0, got {self.quadratic_per_m}, {self.offset_m}"
            )

    def sigma_m(self, depth_m: _Depth) -> _Depth:
        """The noise (m) at ``depth_m`` (m; a number, an array or a tensor, elementwise)."""
        return self.base_m + self.quadratic_per_m * (depth_m - self.offset_m) ** 2

    def weights(self, depth: Tensor) -> Tensor:  # [N] m, 0 = invalid -> [N] float32
        """Each point's weight: the noise at the median valid depth over the noise at its own depth.

        A residual times its weight is in metres of error at the image's typical depth, so a Huber
        threshold keeps its meaning there and the depth term keeps its weight against others;
        0 where the depth is invalid. No host read (the median ignores invalid depths as NaN).
        """
        depth = depth.float()
        valid = depth > 0
        unit = torch.where(valid, depth, torch.nan).nanmedian().nan_to_num(_NO_DEPTH_UNIT_M)
        return torch.where(valid, self.sigma_m(unit) / self.sigma_m(depth), 0.0)
