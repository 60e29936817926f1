"""The compiled renderer's frustum culling: the same images and gradients as the whole map's, bit for bit."""

import pytest
import torch

import sgs_slam_core.kernels.cpu.render as cpu_render
from sgs_slam_core.geometry import se3_exp
from sgs_slam_core.kernels import render
from sgs_slam_core.kernels.cpu.extensions import RENDER
from sgs_slam_core.render import RenderSettings
from sgs_slam_core.render.projection import frustum_candidates, project_gaussians

from .scenes import random_scene

pytestmark = pytest.mark.skipif(
    not RENDER.is_available(), reason=f"compiled backend unavailable: {RENDER.unavailable_reason()}"
)

FIELDS = ("means", "log_scales", "logit_opacities", "colors", "semantics")


def wide_scene(seed: int = 0):
    """A map of which the camera sees about a third: the rest beside, above or behind it."""
    gm, k = random_scene(3000, 64, 48, seed=seed, behind=300)
    g = torch.Generator().manual_seed(seed + 1)
    means = gm.means.clone()
    means[300:2000, 0] += torch.empty(1700).uniform_(-8.0, 8.0, generator=g)  # many beside the frustum
    means[2010:2020, 0] = 2.5  # beside the image, but 1.6 m across: reaching into it
    log_scales = gm.log_scales.clone()
    log_scales[2010:2020] = 0.5
    log_scales[2020:2025] = float("nan")
    return gm.with_tensors(means=means, log_scales=log_scales), k


def pose(dtype=torch.float32):
    return se3_exp(torch.tensor([0.02, -0.01, 0.03, 0.01, -0.02, 0.015], dtype=dtype))


def touching(gm, k, w2c, s):
    """Ids of the Gaussians whose footprint overlaps a pixel, by the reference projection."""
    cam = gm.means @ w2c[:3, :3].T + w2c[:3, 3]
    proj = project_gaussians(cam, gm.opacities, k, s, scales=gm.scales[:, 0])
    u, v, r = proj.means2d[:, 0], proj.means2d[:, 1], proj.radii
    hit = (r > 0) & (torch.ceil(u - r) <= k.width - 1) & (torch.floor(u + r) >= 0)
    hit &= (torch.ceil(v - r) <= k.height - 1) & (torch.floor(v + r) >= 0)
    return torch.nonzero(hit).squeeze(1)


def test_the_candidates_hold_every_touching_gaussian_and_match_the_reference():
    gm, k = wide_scene()
    s, w2c = RenderSettings(), pose()
    cam = (k.fx, k.fy, k.cx, k.cy, k.width, k.height, s.near_plane, s.eps2d, s.extent_sigma)
    for threads in (1, 2, 3):
        got = RENDER.module().frustum_candidates(gm.means, gm.log_scales, w2c, *cam, threads)
        ref = frustum_candidates(gm.means, gm.log_scales, w2c, k, s)
        assert torch.equal(got, ref), threads
    touch = touching(gm, k, w2c, s)
    assert 300 < len(touch) <= len(ref) < 0.6 * len(gm)
    assert torch.isin(touch, ref).all()
    assert torch.isin(torch.arange(2010, 2020), touch).all()
    assert torch.isin(torch.arange(2010, 2025), ref).all()  # huge and NaN scales stay in
    assert not torch.isin(torch.arange(300), ref).any()  # behind the camera


def forward_backward(gm, k, monkeypatch, share):
    monkeypatch.setattr(cpu_render, "CULL_MIN_SHARE", share)
    params = {n: getattr(gm, n).clone().requires_grad_(True) for n in FIELDS}
    xi = torch.zeros(6, requires_grad=True)
    out = render(gm.with_tensors(**params), k, se3_exp(xi) @ pose(), RenderSettings(backend="cpu"))
    g = torch.Generator().manual_seed(5)
    images = (out.color, out.depth, out.silhouette, out.semantic)
    sum((t * torch.randn(t.shape, generator=g)).sum() for t in images).backward()
    return images, {n: p.grad for n, p in params.items()} | {"pose": xi.grad}


def test_a_culled_render_is_the_whole_maps_bit_for_bit(monkeypatch):
    gm, k = wide_scene(seed=3)
    gm = gm.with_tensors(log_scales=torch.nan_to_num(gm.log_scales, nan=-3.0))  # finite gradients to compare
    culled, g_culled = forward_backward(gm, k, monkeypatch, share=0.1)
    whole, g_whole = forward_backward(gm, k, monkeypatch, share=1.0)  # never leaves enough out: no culling
    for a, b in zip(culled, whole, strict=True):
        assert torch.equal(a, b)
    assert culled[2].amax() > 0.5  # something is seen
    for name, grad in g_whole.items():
        assert torch.equal(g_culled[name], grad), name
    out = frustum_candidates(gm.means, gm.log_scales, pose(), k, RenderSettings())
    left = torch.ones(len(gm), dtype=torch.bool)
    left[out] = False
    assert left.sum() > 1000 and (g_culled["means"][left] == 0).all() and (g_culled["colors"][left] == 0).all()


def test_nothing_in_view_renders_empty(monkeypatch):
    gm, k = random_scene(500, 32, 24, seed=1)
    gm = gm.with_tensors(means=gm.means * torch.tensor([1.0, 1.0, -1.0]))  # all behind the camera
    images, grads = forward_backward(gm, k, monkeypatch, share=0.1)
    assert (images[2] == 0).all() and (grads["means"] == 0).all() and grads["means"].shape == gm.means.shape


def test_double_maps_are_not_culled():
    gm, k = random_scene(50, 16, 12, dtype=torch.float64)
    cam = cpu_render.CameraArgs.of(k)
    assert cpu_render.frustum_cull(gm.means, gm.log_scales, pose(torch.float64), cam, RenderSettings()) is None


def test_rows_out_of_range_are_refused():
    gm, k = random_scene(20, 16, 12)
    s, ext = RenderSettings(), RENDER.module()
    cam = (k.fx, k.fy, k.cx, k.cy, k.width, k.height, s.near_plane, s.eps2d, s.alpha_min, s.extent_sigma, 1)
    params = (gm.means, gm.log_scales, gm.logit_opacities, gm.colors, gm.semantics, pose())
    with pytest.raises(RuntimeError, match="rows must index"):
        ext.prepare_world_rows(*params, *cam, torch.tensor([3, 20]))
    with pytest.raises(RuntimeError, match="must be"):
        ext.frustum_candidates(gm.means[:, :2].contiguous(), gm.log_scales, pose(), *cam[:8], s.extent_sigma, 1)
