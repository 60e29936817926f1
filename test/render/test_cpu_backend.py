"""The compiled CPU backend against the torch reference (forward, backward, determinism, fallback)."""

import pytest
import torch

from sgs_slam_core.errors import BackendUnavailableError
from sgs_slam_core.geometry import se3_exp
from sgs_slam_core.kernels import render
from sgs_slam_core.kernels.cpu.extensions import RENDER
from sgs_slam_core.kernels.factory import resolve_backend
from sgs_slam_core.render import RenderSettings

from .scenes import random_scene
from .test_gradients import check

pytestmark = pytest.mark.skipif(
    not RENDER.is_available(), reason=f"compiled backend unavailable: {RENDER.unavailable_reason()}"
)

FIELDS = ("means", "log_scales", "logit_opacities", "colors", "semantics")


def forward_backward(gm, k, backend, channels=("color", "depth", "silhouette", "semantic"), **settings):
    fields = FIELDS + (("quats",) if gm.quats is not None else ())
    params = {n: getattr(gm, n).clone().requires_grad_(True) for n in fields}
    xi = torch.zeros(6, dtype=gm.means.dtype, requires_grad=True)
    w2c = se3_exp(xi) @ se3_exp(torch.tensor([0.02, -0.01, 0.03, 0.01, -0.02, 0.015], dtype=gm.means.dtype))
    out = render(gm.with_tensors(**params), k, w2c, RenderSettings(backend=backend, **settings))
    g = torch.Generator().manual_seed(5)
    outputs = [getattr(out, c) for c in channels]
    loss = sum((t * torch.randn(t.shape, generator=g, dtype=t.dtype)).sum() for t in outputs)
    loss.backward()
    return out, {n: p.grad for n, p in params.items()} | {"pose": xi.grad}


# (dtype, forward tolerance (absolute), gradient tolerance (relative to the largest entry))
TOLERANCES = ((torch.float64, 1e-12, 1e-10), (torch.float32, 2e-5, 2e-4))


def assert_parity(n, w, h, seed, scene=None, **settings):
    """Compiled vs torch forward and gradients on a random scene, in float64 and float32."""
    for dtype, fwd_tol, grad_tol in TOLERANCES:
        gm, k = random_scene(n, w, h, seed=seed, dtype=dtype, **(scene or {}))
        ref, g_ref = forward_backward(gm, k, "torch", **settings)
        got, g_got = forward_backward(gm, k, "cpu", **settings)
        assert got.backend == "cpu" and ref.silhouette.max() > 0.5
        assert got.semantic.shape == ref.semantic.shape
        for name in ("color", "depth", "silhouette", "semantic"):
            assert (getattr(got, name) - getattr(ref, name)).abs().max().item() < fwd_tol, name
        for name, grad in g_ref.items():
            assert (g_got[name] - grad).abs().max().item() <= grad_tol * grad.abs().max().item(), name


@pytest.mark.parametrize(
    ("n", "w", "h", "kwargs", "settings"),
    [
        (300, 40, 30, {}, {}),
        (2000, 97, 61, {"behind": 200}, {}),  # partial tiles, Gaussians behind the camera
        (1500, 128, 96, {}, {"cpu_tile_size": 16}),
        (1500, 100, 70, {}, {"cpu_tile_size": 8}),
        (800, 64, 48, {}, {"cpu_tile_size": 4, "min_transmittance": 0.0}),
        (600, 64, 48, {"anisotropic": True}, {}),  # torch projection, compiled compositing
    ],
)
def test_parity_with_the_torch_reference(n, w, h, kwargs, settings):
    assert_parity(n, w, h, seed=n, scene=kwargs, **settings)


@pytest.mark.parametrize("anisotropic", [False, True])
@pytest.mark.parametrize("channels", [("color",), ("depth", "silhouette"), ("semantic",), ("silhouette",)])
def test_gradients_when_only_some_channels_enter_the_loss(channels, anisotropic):
    gm, k = random_scene(400, 48, 36, seed=4, dtype=torch.float64, anisotropic=anisotropic)
    _, g_ref = forward_backward(gm, k, "torch", channels)
    _, g_got = forward_backward(gm, k, "cpu", channels)
    for name, grad in g_ref.items():
        if grad is None:  # the field does not influence these channels (colours for a depth loss)
            assert g_got[name] is None or not g_got[name].any(), name
            continue
        assert (g_got[name] - grad).abs().max().item() <= 1e-10 * (grad.abs().max().item() + 1e-30), name


def test_one_gaussian_covering_the_image_and_empty_tiles():
    gm, k = random_scene(3, 96, 64, seed=2, dtype=torch.float64)
    gm = gm.with_tensors(
        means=torch.tensor([[0.0, 0.0, 2.0], [9.0, 9.0, 2.0], [0.05, 0.0, 3.0]], dtype=torch.float64),
        log_scales=torch.tensor([[1.5], [0.01], [0.02]], dtype=torch.float64).log(),
    )
    ref, g_ref = forward_backward(gm, k, "torch")
    got, g_got = forward_backward(gm, k, "cpu")
    assert got.silhouette.min() > 0.01
    assert (got.color - ref.color).abs().max() < 1e-12
    assert all((g_got[n] - g_ref[n]).abs().max() <= 1e-10 * (g_ref[n].abs().max() + 1e-30) for n in g_ref)


def test_extreme_parameters_match_the_reference_in_float32():
    """The float kernels' polynomial exp and log (and their clamps) on saturated opacities and scales."""
    gm, k = random_scene(500, 64, 48, seed=6)
    logit = gm.logit_opacities.clone()
    logit[:40], logit[40:80], logit[80:100] = -120.0, 120.0, -5.5  # sigmoid 0, 1, just below alpha_min
    log_scales = gm.log_scales.clone()
    log_scales[100:120], log_scales[120:125] = -30.0, 0.3  # far below a pixel, a metre across
    gm = gm.with_tensors(logit_opacities=logit, log_scales=log_scales)
    ref, g_ref = forward_backward(gm, k, "torch")
    got, g_got = forward_backward(gm, k, "cpu")
    for name in ("color", "depth", "silhouette", "semantic"):
        assert (getattr(got, name) - getattr(ref, name)).abs().max().item() < 2e-5, name
    for name, grad in g_ref.items():
        assert torch.isfinite(g_got[name]).all(), name
        assert (g_got[name] - grad).abs().max().item() <= 2e-4 * grad.abs().max().item(), name


def test_the_simd_preparation_is_the_scalar_one_bit_for_bit():
    """Gaussians in SIMD lanes (all but the last n % W) against each one alone (the scalar path)."""
    gm, k = random_scene(203, 64, 48, seed=7, behind=20)
    logit = gm.logit_opacities.clone()
    logit[30:40] = -6.0  # opacity 0.0025, below alpha_min: culled
    s = RenderSettings()
    ext = RENDER.module()
    pose = torch.tensor([[0.0, -1, 0, 0.1], [1, 0, 0, -0.2], [0, 0, 1, 0.3], [0, 0, 0, 1]])
    params = (gm.means, gm.log_scales, logit, gm.colors, gm.semantics)
    cam = (k.fx, k.fy, k.cx, k.cy, k.width, k.height, s.near_plane, s.eps2d, s.alpha_min, s.extent_sigma)
    whole = ext.prepare_world_isotropic(*params, pose, *cam, 2)
    rows = [ext.prepare_world_isotropic(*(p[i : i + 1] for p in params), pose, *cam, 1) for i in range(203)]
    assert (whole[6] > 0).sum() > 100 and (whole[6] == 0).sum() >= 30
    for j, out in enumerate(whole):
        assert torch.equal(out, torch.cat([r[j] for r in rows])), j


def test_finite_differences_on_the_compiled_path():
    gm, k = random_scene(60, 24, 18, seed=3, dtype=torch.float64)
    settings = RenderSettings(backend="cpu")

    def loss(x, field):
        out = render(gm.with_tensors(**{field: x}), k, torch.eye(4, dtype=torch.float64), settings)
        g = torch.Generator().manual_seed(11)
        return sum(
            (t * torch.randn(t.shape, generator=g, dtype=t.dtype)).sum()
            for t in (out.color, out.depth, out.silhouette, out.semantic)
        )

    for field in FIELDS:
        check(lambda x, f=field: loss(x, f), getattr(gm, field), entries=5)


def test_deterministic_across_runs_and_thread_counts():
    gm, k = random_scene(3000, 120, 90, seed=8)
    before = torch.get_num_threads()
    results = []
    try:
        for threads in (1, 2, 1):
            torch.set_num_threads(threads)
            results.append(forward_backward(gm, k, "cpu"))
    finally:
        torch.set_num_threads(before)
    (a, ga), (b, gb), (c, gc) = results
    assert torch.equal(a.color, b.color) and torch.equal(a.color, c.color)
    assert all(torch.equal(ga[n], gb[n]) and torch.equal(ga[n], gc[n]) for n in ga)


def test_binning_is_the_same_for_any_number_of_parts():
    g = torch.Generator().manual_seed(4)
    n = 5000
    means2d = torch.rand(n, 2, generator=g) * torch.tensor([200.0, 150.0]) - 20  # some off-image
    radii = torch.rand(n, generator=g) * 12
    radii[::7] = 0  # culled
    depths = torch.rand(n, generator=g) * 5 + 0.1
    depths[::11] = depths[3]  # ties keep index order
    ext = RENDER.module()
    one = ext.bin_gaussians(means2d, radii, depths, 160, 120, 16, 1)
    assert one[0].numel() > n
    for parts in (2, 3, 7):
        many = ext.bin_gaussians(means2d, radii, depths, 160, 120, 16, parts)
        assert torch.equal(one[0], many[0]) and torch.equal(one[1], many[1])


def test_auto_picks_the_compiled_backend_and_falls_back_with_a_reason(monkeypatch):
    assert resolve_backend("auto", torch.device("cpu")) == "cpu"
    monkeypatch.setattr(RENDER, "_module", None)
    monkeypatch.setattr(RENDER, "_error", "no compiler in this test")
    assert resolve_backend("auto", torch.device("cpu")) == "torch"
    with pytest.raises(BackendUnavailableError, match="no compiler in this test"):
        resolve_backend("cpu", torch.device("cpu"))


def test_every_tile_size_renders_the_same_image():
    """Packs skipped by the footprint masks hold no alpha: any tile size gives the same image.

    Equal to float rounding: pixel offsets are taken from tile-relative centres.
    """
    gm, k = random_scene(2500, 131, 77, seed=12)
    runs = {tile: forward_backward(gm, k, "cpu", cpu_tile_size=tile) for tile in (4, 8, 16, 32)}
    (ref, g_ref), *others = runs.values()
    for out, grads in others:
        for name in ("color", "depth", "silhouette", "semantic"):
            assert (getattr(out, name) - getattr(ref, name)).abs().max().item() < 1e-5, name
        for name, grad in g_ref.items():
            assert (grads[name] - grad).abs().max().item() <= 1e-5 * grad.abs().max().item(), name


def test_gradients_of_a_loss_over_part_of_the_image():
    """Packs without upstream gradient are skipped by the backward: the result must not change."""
    gm, k = random_scene(1200, 100, 70, seed=21, dtype=torch.float64)
    mask = torch.zeros(70, 100, dtype=torch.float64)
    mask[10:40, 5:37] = 1.0  # not aligned to tiles or packs
    grads = {}
    for backend in ("torch", "cpu"):
        params = {n: getattr(gm, n).clone().requires_grad_(True) for n in FIELDS}
        out = render(gm.with_tensors(**params), k, torch.eye(4, dtype=torch.float64), RenderSettings(backend=backend))
        masked = (out.color * mask[..., None]).sum() + (out.semantic * mask[..., None]).square().sum()
        (masked + (out.depth * mask).square().sum()).backward()
        grads[backend] = {n: p.grad for n, p in params.items()}
    for name, grad in grads["torch"].items():
        assert grad.abs().max() > 0, name
        assert (grads["cpu"][name] - grad).abs().max().item() <= 1e-10 * grad.abs().max().item(), name


def test_without_semantics_the_semantic_group_is_empty():
    gm, k = random_scene(500, 64, 48, seed=6, dtype=torch.float64)
    outs = {
        b: render(gm, k, torch.eye(4, dtype=torch.float64), RenderSettings(backend=b), with_semantics=False)
        for b in ("torch", "cpu")
    }
    assert outs["cpu"].semantic.shape == (48, 64, 0)
    assert (outs["cpu"].color - outs["torch"].color).abs().max() < 1e-12


def test_the_build_without_avx512_matches_the_reference(monkeypatch):
    """The paths of CPUs without AVX-512 (8-lane packs, 16 px tiles, portable exp and sums)."""
    ext = RENDER.variant("noavx512", ("-mno-avx512f",))
    assert ext.max_tile(False) == 16 and ext.max_tile(True) == 16
    monkeypatch.setattr(RENDER, "_module", ext)
    assert_parity(1500, 97, 61, seed=32, scene={"behind": 100})


@pytest.mark.parametrize("semantic", [1, 12])  # channel counts without a specialised kernel (D = 5, 16)
def test_any_channel_count(semantic):
    assert_parity(700, 70, 50, seed=semantic, scene={"semantic": semantic})
