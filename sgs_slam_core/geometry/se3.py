"""SE(3), SO(3) and quaternion helpers (torch, batched, dtype-preserving, float64-safe).

Conventions: quaternions are (w, x, y, z) and need not be normalised on input; poses are 4x4
homogeneous matrices; ``c2w`` maps camera (optical frame: x right, y down, z forward) to world.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
import torch
from torch import Tensor

from sgs_slam_core.errors import ShapeError
from sgs_slam_core.geometry.products import fusable_matmul

__all__ = [
    "quat_multiply",
    "quat_normalize",
    "quat_to_rotmat",
    "quat_xyzw_to_matrix",
    "rotation_angle_deg",
    "rotmat_to_quat",
    "se3_exp",
    "se3_from_rt",
    "se3_inverse",
    "so3_exp",
    "so3_log",
    "transform_points",
]


def quat_xyzw_to_matrix(x: float, y: float, z: float, w: float) -> np.ndarray:  # [3, 3] float64
    """Rotation matrix of an xyzw quaternion (ROS, TUM order), normalised here.

    A zero or non-finite quaternion raises :class:`ShapeError`. Host numpy; the tensor form is
    :func:`quat_to_rotmat`.
    """
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if not math.isfinite(n):
        raise ShapeError(f"not a finite quaternion (x y z w = {x}, {y}, {z}, {w})")
    if n < 1e-9:
        raise ShapeError(f"a zero quaternion (x y z w = {x}, {y}, {z}, {w}) is not a rotation")
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def rotation_angle_deg(rot: np.ndarray) -> np.ndarray:  # [..., 3, 3] -> [...] degrees
    """The angle of each rotation matrix (deg, in [0, 180])."""
    cos = (np.trace(rot, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def _check_last(x: Tensor, dims: tuple[int, ...], name: str) -> None:
    if x.shape[x.ndim - len(dims) :] != dims:
        raise ShapeError(f"{name} must have trailing shape {dims}, got {tuple(x.shape)}")


def quat_normalize(q: Tensor) -> Tensor:  # [..., 4] -> [..., 4]
    """Unit quaternion; a zero quaternion raises rather than producing NaN."""
    _check_last(q, (4,), "quaternion")
    norm = q.norm(dim=-1, keepdim=True)
    if bool((norm == 0).any()):
        raise ShapeError("cannot normalise a zero quaternion")
    return q / norm


def quat_to_rotmat(q: Tensor) -> Tensor:  # [..., 4] wxyz -> [..., 3, 3]
    """Rotation matrix of a (not necessarily normalised) wxyz quaternion; differentiable."""
    _check_last(q, (4,), "quaternion")
    q = q / q.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    rows = (
        1 - 2 * (y * y + z * z),
        2 * (x * y - w * z),
        2 * (x * z + w * y),
        2 * (x * y + w * z),
        1 - 2 * (x * x + z * z),
        2 * (y * z - w * x),
        2 * (x * z - w * y),
        2 * (y * z + w * x),
        1 - 2 * (x * x + y * y),
    )
    return torch.stack(rows, dim=-1).reshape(*q.shape[:-1], 3, 3)


def rotmat_to_quat(rot: Tensor) -> Tensor:  # [..., 3, 3] -> [..., 4] wxyz with w >= 0
    """Unit quaternion of a rotation matrix (Shepperd's method, stable for all angles)."""
    _check_last(rot, (3, 3), "rotation")
    m = rot
    trace = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    # Four candidate solutions; pick per element the one with the largest pivot.
    cands = torch.stack(
        [
            torch.stack(
                [1 + trace, m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], -1
            ),
            torch.stack(
                [
                    m[..., 2, 1] - m[..., 1, 2],
                    1 + m[..., 0, 0] - m[..., 1, 1] - m[..., 2, 2],
                    m[..., 0, 1] + m[..., 1, 0],
                    m[..., 0, 2] + m[..., 2, 0],
                ],
                -1,
            ),
            torch.stack(
                [
                    m[..., 0, 2] - m[..., 2, 0],
                    m[..., 0, 1] + m[..., 1, 0],
                    1 - m[..., 0, 0] + m[..., 1, 1] - m[..., 2, 2],
                    m[..., 1, 2] + m[..., 2, 1],
                ],
                -1,
            ),
            torch.stack(
                [
                    m[..., 1, 0] - m[..., 0, 1],
                    m[..., 0, 2] + m[..., 2, 0],
                    m[..., 1, 2] + m[..., 2, 1],
                    1 - m[..., 0, 0] - m[..., 1, 1] + m[..., 2, 2],
                ],
                -1,
            ),
        ],
        dim=-2,
    )  # [..., 4, 4]: candidate k is 4 * q_k * q (times a sign)
    diag = (m[..., 0, 0], m[..., 1, 1], m[..., 2, 2])
    pivots = torch.stack(
        [1 + trace, 1 + diag[0] - diag[1] - diag[2], 1 - diag[0] + diag[1] - diag[2], 1 - diag[0] - diag[1] + diag[2]],
        -1,
    )
    best = pivots.argmax(dim=-1)
    q = torch.gather(cands, -2, best[..., None, None].expand(*best.shape, 1, 4)).squeeze(-2)
    q = q / q.norm(dim=-1, keepdim=True)
    return torch.where(q[..., :1] < 0, -q, q)


def quat_multiply(a: Tensor, b: Tensor) -> Tensor:  # [..., 4] x [..., 4] -> [..., 4]
    """Hamilton product a * b of wxyz quaternions (rotation b first, then a)."""
    _check_last(a, (4,), "quaternion a")
    _check_last(b, (4,), "quaternion b")
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        dim=-1,
    )


def se3_from_rt(rot: Tensor, trans: Tensor) -> Tensor:  # [..., 3, 3], [..., 3] -> [..., 4, 4]
    """Homogeneous matrix from rotation and translation (differentiable)."""
    _check_last(rot, (3, 3), "rotation")
    _check_last(trans, (3,), "translation")
    top = torch.cat([rot, trans[..., :, None]], dim=-1)
    bottom = _constant(((0.0, 0.0, 0.0, 1.0),), top.dtype, top.device)
    return torch.cat([top, bottom.expand(*top.shape[:-2], 1, 4)], dim=-2)


def se3_inverse(pose: Tensor) -> Tensor:  # [..., 4, 4] -> [..., 4, 4]
    """Inverse of a rigid transform using R^T (exact for rigid poses, differentiable)."""
    _check_last(pose, (4, 4), "pose")
    rot_t = pose[..., :3, :3].transpose(-1, -2)
    trans = -(rot_t @ pose[..., :3, 3:4])[..., 0]
    return se3_from_rt(rot_t, trans)


def transform_points(pose: Tensor, points: Tensor) -> Tensor:  # [4, 4], [N, 3] -> [N, 3]
    """Apply a rigid transform to row-vector points."""
    _check_last(pose, (4, 4), "pose")
    _check_last(points, (3,), "points")
    return points @ pose[:3, :3].transpose(0, 1) + pose[:3, 3]


# Generators of so(3): skew(w) = sum_i w_i G_i, as one [3, 9] matrix (one matmul, not nine stacked scalars).
_GENERATORS = ((0, 0, 0, 0, 0, -1, 0, 1, 0), (0, 0, 1, 0, 0, 0, -1, 0, 0), (0, -1, 0, 1, 0, 0, 0, 0, 0))
# Taylor coefficients near 0 of sin(t)/t, (1 - cos t)/t^2, (t - sin t)/t^3: c0 + c1 t^2.
_TAYLOR = ((1.0, 0.5, 1.0 / 6.0), (-1.0 / 6.0, -1.0 / 24.0, -1.0 / 120.0))


def _constant(values: tuple, dtype: torch.dtype, device: torch.device) -> Tensor:
    """A small constant tensor, made once per dtype and device (a fresh host-to-GPU copy would sync).

    While ``torch.compile`` traces, a fresh one: the compiled graph holds it as a constant.
    """
    if torch.compiler.is_compiling():
        return torch.tensor(values, dtype=dtype, device=device)
    return _cached_constant(values, dtype, device)


@lru_cache(maxsize=32)
def _cached_constant(values: tuple, dtype: torch.dtype, device: torch.device) -> Tensor:
    return torch.tensor(values, dtype=dtype, device=device)


def _skew(w: Tensor) -> Tensor:  # [..., 3] -> [..., 3, 3]
    return fusable_matmul(w[..., None, :], _constant(_GENERATORS, w.dtype, w.device)).reshape(*w.shape[:-1], 3, 3)


def _rodrigues(omega: Tensor) -> tuple[Tensor, Tensor, Tensor]:  # [..., 3] -> 3 x [..., 1, 1]
    """``(a, b, c)`` = sin(t)/t, (1 - cos t)/t^2, (t - sin t)/t^3 with t = |omega|.

    A first-order Taylor expansion below t^2 = 1e-8 keeps values and gradients smooth at 0.
    """
    theta2 = (omega * omega).sum(-1, keepdim=True)[..., None]  # [..., 1, 1]
    small = theta2 < 1e-8
    t2 = torch.where(small, torch.ones_like(theta2), theta2)
    t = t2.sqrt()
    sin, one_minus_cos = torch.sin(t), 1 - torch.cos(t)
    exact = torch.cat([sin / t, one_minus_cos / t2, (t - sin) / (t2 * t)], dim=-1)  # [..., 1, 3]
    c0, c1 = (_constant(c, omega.dtype, omega.device) for c in _TAYLOR)
    coef = torch.where(small, c0 + c1 * theta2, exact).unsqueeze(-1)  # [..., 1, 3, 1]
    a, b, c = coef.unbind(-2)
    return a, b, c


def so3_exp(omega: Tensor) -> Tensor:  # [..., 3] axis-angle (rad) -> [..., 3, 3]
    """Rodrigues' formula with a Taylor expansion near zero (smooth gradients at the identity)."""
    _check_last(omega, (3,), "axis-angle")
    a, b, _ = _rodrigues(omega)
    k = _skew(omega)
    eye = torch.eye(3, dtype=omega.dtype, device=omega.device)
    return eye + a * k + b * (k @ k)


def so3_log(rot: Tensor) -> Tensor:  # [..., 3, 3] -> [..., 3] axis-angle (rad)
    """Inverse of :func:`so3_exp`, via the quaternion (stable up to and including pi)."""
    q = rotmat_to_quat(rot)
    vec = q[..., 1:]
    sin_half = vec.norm(dim=-1, keepdim=True)
    half = torch.atan2(sin_half, q[..., :1])
    scale = torch.where(sin_half < 1e-12, 2.0 / q[..., :1].clamp_min(1e-12), 2 * half / sin_half.clamp_min(1e-12))
    return vec * scale


def se3_exp(xi: Tensor) -> Tensor:  # [..., 6] (rho, phi) -> [..., 4, 4]
    """Exponential map of se(3); ``rho`` is the translation part (m), ``phi`` the rotation (rad)."""
    _check_last(xi, (6,), "se(3) vector")
    rho, phi = xi[..., :3], xi[..., 3:]
    a, b, c = _rodrigues(phi)
    k = _skew(phi)
    kk = fusable_matmul(k, k)
    eye = torch.eye(3, dtype=xi.dtype, device=xi.device)
    rot = eye + a * k + b * kk
    v = eye + b * k + c * kk  # left Jacobian of SO(3)
    return se3_from_rt(rot, fusable_matmul(v, rho[..., None])[..., 0])
