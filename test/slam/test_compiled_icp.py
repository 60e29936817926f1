"""The ICP through ``torch.compile`` (``render.compile``) against ``geometry.icp``'s PyTorch code run eagerly."""

from __future__ import annotations

import logging

import numpy as np
import pytest
import torch

from sgs_slam_core.config.sections import GaussNewtonSettings
from sgs_slam_core.errors import ShapeError
from sgs_slam_core.geometry import icp, se3_exp
from sgs_slam_core.geometry.depth_noise import DepthNoise
from sgs_slam_core.kernels import build_kernels
from sgs_slam_core.kernels.compiled import CompiledFunction, compiled_icp_kernels
from sgs_slam_core.kernels.cpu.extensions import GAUSS_NEWTON
from sgs_slam_core.render import RenderSettings

from .test_gauss_newton import _one_level_alignment, gn_tracker, target_frame

COMPILED = compiled_icp_kernels()


def test_the_compiled_steps_terms_and_joint_step_match_the_pytorch_code():
    ref, points, values = _one_level_alignment([0.02, 0.0, -0.01, 0.01, 0.0, 0.02])
    weights = DepthNoise().weights(points[:, 2])
    s = icp.IcpSettings(max_distance_m=0.2)
    start = torch.eye(4, dtype=torch.float64)
    slow = start
    for _ in range(3):
        slow = icp.torch_step(slow, points, values, weights, ref, s)
    fast = COMPILED.steps(start, points, values, weights, ref, s, 3)
    assert not torch.allclose(slow, start, atol=1e-4)  # the steps moved the pose
    assert torch.allclose(fast, slow, atol=1e-6), (fast - slow).abs().max()

    pose = se3_exp(torch.tensor([0.005, 0.0, 0.0, 0.0, 0.01, 0.0], dtype=torch.float64))
    args = (pose, points, values, ref.packed, ref.intrinsics, s.max_distance_m, s.huber_m, weights)
    fast_terms, slow_terms = COMPILED.terms(*args), icp.torch_terms(*args)
    scale = float(slow_terms[:49].abs().max())
    assert torch.allclose(fast_terms[:49], slow_terms[:49], rtol=1e-4, atol=1e-6 * scale)
    assert torch.allclose(fast_terms[49:], slow_terms[49:], rtol=1e-5) and slow_terms[50] > 500

    k = ref.intrinsics
    seen = points[points[:, 2] > 0][::97].double()  # [M, 3] as landmarks: in the rendered camera at the pose
    pixels = torch.stack([seen[:, 0] / seen[:, 2] * k.fx + k.cx, seen[:, 1] / seen[:, 2] * k.fy + k.cy], dim=-1)
    for count in (len(seen), len(seen) - 7):  # the observations' count changes from frame to frame
        obs = icp.Observations(seen[:count] @ pose[:3, :3].T + pose[:3, 3], pixels[:count], 4.0, 2.0)
        slow = icp.torch_joint_step(pose, points, values, weights, ref, s, obs)
        fast = COMPILED.joint(pose, points, values, weights, ref, s, obs)
        assert torch.allclose(fast, slow, atol=1e-6), (fast - slow).abs().max()


def test_the_compiled_level_matches_the_pytorch_level():
    _, frame = target_frame()
    depth = frame.depth.clone()
    depth[::7, ::5] = 0.0
    k = frame.intrinsics
    for fast, slow in zip(icp.icp_pyramid(depth, k, 2, COMPILED.level), icp.icp_pyramid(depth, k, 2), strict=True):
        assert torch.equal(fast.valid, slow.valid) and slow.valid.sum() > 100
        assert torch.allclose(fast.packed, slow.packed, atol=1e-6)


def test_the_tracker_on_compiled_kernels_finds_the_pose_the_eager_one_finds():
    gm, frame = target_frame()
    start = se3_exp(torch.tensor([0.02, 0.0, 0.01, 0.0, 0.02, 0.0], dtype=torch.float64)).numpy()
    settings = GaussNewtonSettings(iterations=(4, 4))
    eager, compiled = gn_tracker(settings), gn_tracker(settings)
    compiled.kernels = build_kernels(RenderSettings(backend="torch", compile=True), "cpu")
    assert compiled.kernels.icp.steps is not None and eager.kernels.icp.steps is None
    slow, fast = (tracker.track(gm, frame, start, True) for tracker in (eager, compiled))
    assert np.linalg.norm(slow.w2c[:3, 3]) < 0.3 * np.linalg.norm(start[:3, 3])
    assert np.abs(fast.w2c - slow.w2c).max() < 1e-5


def test_render_compile_replaces_the_backends_own_icp():
    assert build_kernels(RenderSettings(backend="torch"), "cpu").icp == icp.IcpKernels()
    assert build_kernels(RenderSettings(backend="torch", compile=True), "cpu").icp.joint is not None
    if GAUSS_NEWTON.is_available():  # the C++ ICP has no joint step of its own
        assert build_kernels(RenderSettings(backend="cpu"), "cpu").icp.joint is None
        assert build_kernels(RenderSettings(backend="cpu", compile=True), "cpu").icp.joint is not None


def test_a_failed_compile_warns_once_and_runs_the_function_eagerly(caplog):
    calls: list[int] = []

    def twice(x: torch.Tensor) -> torch.Tensor:
        calls.append(1)
        return x * 2

    def broken(*args: object) -> torch.Tensor:
        raise torch._dynamo.exc.BackendCompilerFailed(broken, RuntimeError("no C++ compiler found"), None)

    function = CompiledFunction(twice)
    function.compiled = broken
    with caplog.at_level(logging.WARNING):
        assert torch.equal(function(torch.ones(2)), torch.full((2,), 2.0))
        assert torch.equal(function(torch.ones(3)), torch.full((3,), 2.0))
    assert len(calls) == 2 and function.failed == "RuntimeError: no C++ compiler found"
    warnings = [r.message for r in caplog.records if "torch.compile" in r.message]
    assert warnings == ["torch.compile of twice failed (RuntimeError: no C++ compiler found); running it eagerly"]


def test_a_users_shape_error_is_raised_before_compiling():
    ref, points, values = _one_level_alignment([0.0] * 6)
    with pytest.raises(ShapeError, match="channels"):
        COMPILED.steps(torch.eye(4, dtype=torch.float64), points, values[:, :1], None, ref, icp.IcpSettings(), 1)
