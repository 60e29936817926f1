"""The ICP's compiled parts (``gauss_newton.cpp``), as ``geometry.icp`` computes them.

One pass over the source points gives a Gauss-Newton step's normal equations and the truncated
cost that ``geometry.icp`` computes with a dozen tensor operations per step; one pass over a depth
image gives a reference level's vertices and normals (two dozen operations there). Tests compare
each with its PyTorch form.
"""

from __future__ import annotations

from torch import Tensor

from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.geometry.icp import IcpKernels, IcpLevel, IcpSettings
from sgs_slam_core.kernels.cpu.extensions import GAUSS_NEWTON

__all__ = ["ICP_KERNELS", "icp_level", "icp_steps", "icp_terms"]


def icp_terms(
    src_to_ref: Tensor,  # [4, 4] float64
    points: Tensor,  # [N, 3] float32 source points, z = 0 where invalid
    values: Tensor | None,  # [N, C] float32 source channels
    packed: Tensor,  # [H * W, 7 (+ 3C + 1)] the reference level's rows
    intrinsics: Intrinsics,  # the reference level's camera
    max_distance_m: float,
    huber_m: float,
    weights: Tensor | None,  # [N] float32 depth-noise weights of the source points
) -> Tensor:  # [53] float64: normal matrix [49], truncated cost, correspondences, their sum r^2, source points
    """The kernel's terms at ``src_to_ref`` (CPU tensors).

    One thread: a frame's few thousand points take well under a millisecond, and a second OpenMP
    thread would spin against the live pipeline's other worker.
    """
    k = intrinsics
    camera = (k.fx, k.fy, k.cx, k.cy, k.width, k.height)
    return GAUSS_NEWTON.module().gauss_newton_terms(
        src_to_ref, points, *_optional(points, values, weights), packed, *camera, max_distance_m, huber_m, 1
    )


def _optional(points: Tensor, values: Tensor | None, weights: Tensor | None) -> tuple[Tensor, Tensor]:
    """The kernel's channel and weight arguments, empty tensors for none."""
    empty = points.new_zeros((0, 0))
    return (empty if values is None else values), (empty if weights is None else weights)


def icp_level(depth: Tensor, intrinsics: Intrinsics, min_normal_cos: float) -> Tensor:
    """``depth`` [H, W] m (0 = invalid, CPU) -> the level's packed rows [H * W, 7] float32 (one thread)."""
    k = intrinsics
    return GAUSS_NEWTON.module().vertex_normal_level(depth.float(), k.fx, k.fy, k.cx, k.cy, min_normal_cos)


def icp_steps(
    src_to_ref: Tensor,  # [4, 4] float64
    points: Tensor,  # [N, 3] float32 source points, z = 0 where invalid
    values: Tensor | None,  # [N, C] float32 source channels
    weights: Tensor | None,  # [N] float32 depth-noise weights of the source points
    ref: IcpLevel,
    s: IcpSettings,
    steps: int,
) -> Tensor:  # [4, 4] float64
    """``steps`` damped Gauss-Newton updates against ``ref`` in one call (CPU tensors, one thread)."""
    k = ref.intrinsics
    camera = (k.fx, k.fy, k.cx, k.cy, k.width, k.height)
    return GAUSS_NEWTON.module().gauss_newton_steps(
        src_to_ref,
        points,
        *_optional(points, values, weights),
        ref.packed,
        *camera,
        s.max_distance_m,
        s.huber_m,
        s.damping,
        steps,
        1,
    )


ICP_KERNELS = IcpKernels(terms=icp_terms, steps=icp_steps, level=icp_level)
