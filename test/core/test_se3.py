import math

import pytest
import torch

from sgs_slam_core.errors import ShapeError
from sgs_slam_core.geometry import (
    quat_multiply,
    quat_normalize,
    quat_to_rotmat,
    rotmat_to_quat,
    se3_exp,
    se3_from_rt,
    se3_inverse,
    so3_exp,
    so3_log,
    transform_points,
)


def random_quats(n: int, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    q = torch.randn(n, 4, generator=g, dtype=torch.float64)
    q = q / q.norm(dim=1, keepdim=True)
    return torch.where(q[:, :1] < 0, -q, q)


def test_quat_rotmat_round_trip_float64():
    q = random_quats(1000)
    rot = quat_to_rotmat(q)
    assert rot.dtype == torch.float64
    eye = torch.eye(3, dtype=torch.float64).expand(1000, 3, 3)
    assert torch.allclose(rot @ rot.transpose(1, 2), eye, atol=1e-14)
    assert torch.allclose(torch.linalg.det(rot), torch.ones(1000, dtype=torch.float64), atol=1e-14)
    assert torch.allclose(rotmat_to_quat(rot), q, atol=1e-13)


def test_rotmat_to_quat_near_pi_and_identity():
    for axis in torch.eye(3, dtype=torch.float64):
        for angle in (0.0, 1e-9, math.pi - 1e-9, math.pi):
            rot = so3_exp(axis * angle)
            assert torch.allclose(quat_to_rotmat(rotmat_to_quat(rot)), rot, atol=1e-12)


def test_quaternion_product_composes_rotations():
    a, b = random_quats(50, 1), random_quats(50, 2)
    assert torch.allclose(quat_to_rotmat(quat_multiply(a, b)), quat_to_rotmat(a) @ quat_to_rotmat(b), atol=1e-13)


def test_so3_exp_log_round_trip_and_known_value():
    g = torch.Generator().manual_seed(3)
    w = torch.randn(200, 3, generator=g, dtype=torch.float64)
    w = w / w.norm(dim=1, keepdim=True) * torch.rand(200, 1, generator=g, dtype=torch.float64) * 3.0
    assert torch.allclose(so3_log(so3_exp(w)), w, atol=1e-10)
    rz90 = so3_exp(torch.tensor([0.0, 0.0, math.pi / 2], dtype=torch.float64))
    assert torch.allclose(rz90, torch.tensor([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]], dtype=torch.float64), atol=1e-15)


def test_so3_exp_gradient_is_finite_at_zero():
    w = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    so3_exp(w).sum().backward()
    assert torch.isfinite(w.grad).all()


def test_se3_inverse_and_transform_points():
    q = random_quats(20, 4)
    t = torch.randn(20, 3, dtype=torch.float64)
    pose = se3_from_rt(quat_to_rotmat(q), t)
    eye = torch.eye(4, dtype=torch.float64).expand(20, 4, 4)
    assert torch.allclose(pose @ se3_inverse(pose), eye, atol=1e-13)
    pts = torch.randn(7, 3, dtype=torch.float64)
    back = transform_points(se3_inverse(pose[0]), transform_points(pose[0], pts))
    assert torch.allclose(back, pts, atol=1e-13)


def test_se3_exp_pure_translation_and_rotation():
    xi = torch.tensor([0.1, -0.2, 0.3, 0.0, 0.0, 0.0], dtype=torch.float64)
    assert torch.allclose(se3_exp(xi)[:3, 3], xi[:3])
    xi = torch.tensor([0.0, 0.0, 0.0, 0.0, 0.0, 0.5], dtype=torch.float64)
    assert torch.allclose(se3_exp(xi)[:3, :3], so3_exp(xi[3:]))


def test_bad_shapes_and_zero_quaternion_raise():
    with pytest.raises(ShapeError, match="trailing shape"):
        quat_to_rotmat(torch.zeros(3))
    with pytest.raises(ShapeError, match="zero quaternion"):
        quat_normalize(torch.zeros(2, 4))
    with pytest.raises(ShapeError):
        se3_inverse(torch.eye(3))
