"""Closed-form checks of the compositing model."""

import math

import pytest
import torch

from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.geometry import Intrinsics
from sgs_slam_core.kernels import render
from sgs_slam_core.render import RenderSettings

K = Intrinsics(100.0, 100.0, 20.0, 15.0, 41, 31)
SETTINGS = RenderSettings(backend="torch")


def gaussians(means, scales, opacities, colors, semantics=None):
    n = len(means)
    return GaussianMap(
        means=torch.tensor(means, dtype=torch.float64),
        log_scales=torch.tensor(scales, dtype=torch.float64).log()[:, None],
        logit_opacities=torch.logit(torch.tensor(opacities, dtype=torch.float64)),
        colors=torch.tensor(colors, dtype=torch.float64),
        semantics=torch.tensor(semantics if semantics is not None else [[0.0]] * n, dtype=torch.float64),
        labels=torch.zeros(n, dtype=torch.long),
        birth_frame=torch.zeros(n, dtype=torch.long),
    )


def test_single_gaussian_alpha_at_centre_and_one_and_two_sigma():
    z, sigma_px, o = 2.0, 4.0, 0.8
    # 2D variance = (s f / z)^2 + eps2d; choose s so that it is exactly sigma_px^2.
    s = math.sqrt(sigma_px**2 - SETTINGS.eps2d) * z / K.fx
    out = render(gaussians([[0.0, 0.0, z]], [s], [o], [[1.0, 0.5, 0.25]]), K, torch.eye(4), SETTINGS)
    cy, cx = 15, 20
    for k_sigma in (0, 1, 2):
        expected = o * math.exp(-0.5 * k_sigma**2)
        for dv, du in ((0, 4 * k_sigma), (4 * k_sigma, 0), (0, -4 * k_sigma)):
            assert out.silhouette[cy + dv, cx + du].item() == pytest.approx(expected, rel=1e-12)
    a = out.silhouette[cy, cx].item()
    assert out.color[cy, cx].tolist() == pytest.approx([a, 0.5 * a, 0.25 * a], rel=1e-12)
    assert out.depth[cy, cx].item() == pytest.approx(a * z, rel=1e-12)
    # Beyond 3 sigma the footprint is cut: exactly zero.
    assert out.silhouette[cy, cx + 13].item() == 0.0


def test_two_gaussians_composite_front_to_back_in_any_input_order():
    near = ([0.0, 0.0, 1.0], 0.2, 0.6, [1.0, 0.0, 0.0])
    far = ([0.0, 0.0, 2.0], 0.4, 0.5, [0.0, 0.0, 1.0])
    for order in ((near, far), (far, near)):
        m = gaussians(*[list(x) for x in zip(*order, strict=True)])
        out = render(m, K, torch.eye(4), SETTINGS)
        color, depth, sil = out.color[15, 20], out.depth[15, 20].item(), out.silhouette[15, 20].item()
        assert color.tolist() == pytest.approx([0.6, 0.0, 0.4 * 0.5], rel=1e-12)
        assert sil == pytest.approx(1 - 0.4 * 0.5, rel=1e-12)
        assert depth == pytest.approx(0.6 * 1.0 + 0.4 * 0.5 * 2.0, rel=1e-12)


def test_opaque_gaussian_depth_is_its_z():
    m = gaussians([[0.1, -0.05, 3.0]], [0.3], [0.999999], [[0.2, 0.2, 0.2]])
    out = render(m, K, torch.eye(4), SETTINGS)
    v, u = 15 + round(-0.05 / 3 * 100), 20 + round(0.1 / 3 * 100)
    assert out.silhouette[v, u].item() == pytest.approx(SETTINGS.alpha_max, abs=1e-3)
    assert (out.depth[v, u] / out.silhouette[v, u]).item() == pytest.approx(3.0, rel=1e-12)


def test_gaussian_behind_the_camera_or_transparent_renders_nothing():
    m = gaussians([[0.0, 0.0, -2.0], [0.0, 0.0, 2.0]], [0.5, 0.5], [0.9, 0.001], [[1.0, 1.0, 1.0]] * 2)
    out = render(m, K, torch.eye(4), SETTINGS)
    assert out.silhouette.abs().max().item() == 0.0
    assert out.color.abs().max().item() == 0.0


def test_pose_moves_the_image():
    m = gaussians([[0.0, 0.0, 2.0]], [0.05], [0.9], [[1.0, 1.0, 1.0]])
    w2c = torch.eye(4, dtype=torch.float64)
    w2c[0, 3] = 0.2  # camera moved left by 0.2 m: the blob appears 0.2 / 2 * fx = 10 px to the right
    out = render(m, K, w2c, SETTINGS)
    v, u = divmod(int(out.silhouette.argmax()), K.width)
    assert (v, u) == (15, 30)


def test_outputs_have_documented_shapes_and_semantics_can_be_skipped():
    m = gaussians([[0.0, 0.0, 2.0]], [0.05], [0.9], [[1.0, 1.0, 1.0]], semantics=[[0.1, 0.2, 0.3, 0.4, 0.5]])
    out = render(m, K, torch.eye(4), SETTINGS)
    assert out.color.shape == (31, 41, 3) and out.depth.shape == (31, 41)
    assert out.silhouette.shape == (31, 41) and out.semantic.shape == (31, 41, 5)
    assert render(m, K, torch.eye(4), SETTINGS, with_semantics=False).semantic.shape == (31, 41, 0)
