"""The compiled CPU kernel of a Gauss-Newton step (``cpu/gauss_newton.cpp``), beside its PyTorch reference.

One pass over the source points gives the step's normal equations and the truncated cost that
``geometry.icp`` computes with a dozen tensor operations per step; tests compare the two.
"""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

from torch import Tensor

from sgs_slam_core.native import NativeExtension

__all__ = ["EXTENSION", "native_terms"]

EXTENSION = NativeExtension("gauss_newton", Path(__file__).with_name("cpu") / "gauss_newton.cpp",
                            "the Gauss-Newton tracker's CPU kernel")  # fmt: skip


def native_terms(
    module: ModuleType,
    src_to_ref: Tensor,  # [4, 4] float64
    points: Tensor,  # [N, 3] float32 source points, z = 0 where invalid
    values: Tensor | None,  # [N, C] float32 source channels
    packed: Tensor,  # [H * W, 7 (+ 3C + 1)] the reference level's rows
    intrinsics: tuple[float, float, float, float, int, int],  # fx, fy, cx, cy, width, height
    max_distance_m: float,
    huber_m: float,
) -> Tensor:  # [53] float64: normal matrix [49], truncated cost, correspondences, their sum r^2, source points
    """The kernel's terms at ``src_to_ref`` (CPU tensors).

    One thread: a frame's few thousand points take well under a millisecond, and a second OpenMP
    thread would spin against the live pipeline's other worker.
    """
    fx, fy, cx, cy, width, height = intrinsics
    empty = points.new_zeros((0, 0))
    return module.gauss_newton_terms(src_to_ref, points, empty if values is None else values, packed, fx, fy, cx, cy,
                                     width, height, max_distance_m, huber_m, 1)  # fmt: skip
