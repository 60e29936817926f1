"""The depth camera's noise model and the weights it gives ICP residuals."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from sgs_slam_core.config import load_config
from sgs_slam_core.errors import ConfigError
from sgs_slam_core.geometry.depth_noise import DepthNoise
from sgs_slam_core.geometry.icp import IcpSettings, align_depth, icp_pyramid
from sgs_slam_core.labels import LabelTable
from sgs_slam_core.synthetic.noise import add_depth_noise
from sgs_slam_core.synthetic.primitives import Box, RoomShell
from sgs_slam_core.synthetic.room import Scene
from sgs_slam_core.synthetic.textures import Material

from .test_icp import K, errors, pose, room_depth

_PLAIN = Material(base=(0.5, 0.5, 0.5))
# two boxes about a metre away in a room whose far wall is 5 m away: most pixels see far, noisy depth
NEAR_AND_FAR = Scene(
    (
        RoomShell(1, _PLAIN, lo=(-3.0, -1.5, -1.0), hi=(3.0, 1.5, 5.0)),
        Box(2, _PLAIN, center=(-0.2, 0.1, 1.0), half=(0.25, 0.3, 0.2)),
        Box(3, _PLAIN, center=(0.4, -0.2, 1.3), half=(0.2, 0.2, 0.2)),
    ),
    LabelTable.nyu40(),
    (-3.0, -1.5, -1.0),
    (3.0, 1.5, 5.0),
)


def test_the_kinect_model_and_its_weights():
    noise = DepthNoise()
    assert noise.sigma_m(1.0) == pytest.approx(0.001884)  # 1.2 mm + 1.9 mm * 0.6^2
    assert noise.sigma_m(np.array([3.0]))[0] == pytest.approx(0.014044)
    depth = torch.tensor([0.0, 1.0, 2.0, 2.0, 3.0, 0.0])  # median valid depth: 2 m
    w = noise.weights(depth)
    assert w[0] == 0 and w[5] == 0 and w[2] == pytest.approx(1.0) and w[3] == pytest.approx(1.0)
    assert w[1] == pytest.approx(noise.sigma_m(2.0) / noise.sigma_m(1.0)) and w[1] > 1 > w[4]
    assert torch.equal(noise.weights(torch.zeros(4)), torch.zeros(4))  # no valid depth: finite, unused


def test_bad_models_are_config_errors():
    with pytest.raises(ConfigError, match="base_m"):
        DepthNoise(base_m=0.0)
    with pytest.raises(ConfigError, match="quadratic_per_m"):
        DepthNoise(quadratic_per_m=-1.0)
    with pytest.raises(ConfigError, match="base_m"):
        load_config("tum", None, ["tracking.gauss_newton.depth_noise.base_m=-0.001"])
    off = load_config("tum", None, ["tracking.gauss_newton.depth_noise=null"])
    assert off.tracking.gauss_newton.icp.depth_noise is None
    assert load_config("tum", None, []).tracking.gauss_newton.icp.depth_noise == DepthNoise()


def test_weighting_by_the_noise_lets_the_near_surfaces_decide():
    """Kinect-like noise on the new frame: the weighted alignment is several times closer to the motion."""
    ref_c2w = pose((0.0, 0.0, 0.0), (2.0, -3.0, 1.0))
    motion = pose((0.02, 0.01, -0.02), (0.5, 1.0, -0.5))
    exact = room_depth(ref_c2w @ motion, NEAR_AND_FAR).numpy()
    ref = icp_pyramid(room_depth(ref_c2w, NEAR_AND_FAR), K, 3)
    error = {None: 0.0, DepthNoise(): 0.0}
    for seed in range(4):
        src = torch.from_numpy(add_depth_noise(exact, 1.0, np.random.default_rng(seed)))
        for noise in error:
            s = IcpSettings(iterations=(10, 10, 10), depth_noise=noise)
            res = align_depth(src, K, ref, torch.eye(4, dtype=torch.float64), s)
            error[noise] += errors(res.src_to_ref.numpy(), motion)[0] / 4
    assert error[DepthNoise()] < 0.4 * error[None] and error[DepthNoise()] < 5e-4  # m


def test_the_compiled_weighted_alignment_matches_the_pytorch_one():
    from sgs_slam_core.kernels.cpu.extensions import GAUSS_NEWTON
    from sgs_slam_core.kernels.cpu.gauss_newton import ICP_KERNELS

    if not GAUSS_NEWTON.is_available():
        pytest.skip(GAUSS_NEWTON.unavailable_reason())
    ref_c2w = pose((0.0, 0.0, 0.0), (2.0, -3.0, 1.0))
    motion = pose((0.02, 0.01, -0.02), (0.5, 1.0, -0.5))
    src = torch.from_numpy(
        add_depth_noise(room_depth(ref_c2w @ motion, NEAR_AND_FAR).numpy(), 1.0, np.random.default_rng(0))
    )
    ref = icp_pyramid(room_depth(ref_c2w, NEAR_AND_FAR), K, 3)
    s = IcpSettings(depth_noise=DepthNoise())
    start = torch.eye(4, dtype=torch.float64)
    torch_result = align_depth(src, K, ref, start, s)
    compiled = align_depth(src, K, ref, start, s, ICP_KERNELS)
    assert torch.allclose(compiled.src_to_ref, torch_result.src_to_ref, atol=1e-5)
    assert compiled.inlier_fraction == pytest.approx(torch_result.inlier_fraction, abs=1e-3)
    assert compiled.rms_m == pytest.approx(torch_result.rms_m, rel=1e-3)  # unweighted metres in both
