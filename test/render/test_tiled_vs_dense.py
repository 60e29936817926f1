"""The tiled renderer against independent references.

* dense all-pairs compositing (no tiles, no chunking, plain autograd): forward and backward;
* the same tile plan blended with plain autograd ops: checks the hand-written backward.
"""

import pytest
import torch

from sgs_slam_core.render import RenderSettings, to_camera
from sgs_slam_core.render.composite import composite, composite_autograd
from sgs_slam_core.render.dense import composite_dense
from sgs_slam_core.render.output import camera_covariances
from sgs_slam_core.render.projection import project_gaussians
from sgs_slam_core.render.tiling import plan_tiles

from .scenes import random_scene

# float32 tolerances: differences come only from summation order (chunked bmm vs one matmul).
FWD_TOL = 2e-5
GRAD_RTOL = 2e-4


def run(gm, k, settings, method):
    params = {name: getattr(gm, name).clone().requires_grad_(True) for name in ("means", "log_scales", "colors")}
    params["logit_opacities"] = gm.logit_opacities.clone().requires_grad_(True)
    w2c = torch.eye(4, dtype=gm.means.dtype, requires_grad=True)
    cam = to_camera(gm.with_tensors(**params), w2c)
    if cam.quats is None:
        proj = project_gaussians(cam.means, cam.opacities, k, settings, scales=cam.scales)
    else:
        proj = project_gaussians(cam.means, cam.opacities, k, settings, covars_cam=camera_covariances(cam))
    feats = torch.cat([cam.features, proj.depths[:, None]], 1)
    if method == "dense":
        img, sil = composite_dense(
            proj.means2d, proj.conics, proj.opacities, feats, proj.depths, proj.radii > 0, k.width, k.height, settings
        )
    else:
        plan = plan_tiles(
            proj.means2d, proj.radii, proj.depths, k.width, k.height, settings.tile_size, settings.chunk_elements
        )
        img, sil = method(proj.means2d, proj.conics, proj.opacities, feats, plan, settings)
    g = torch.Generator().manual_seed(2)
    loss = (img * torch.randn(img.shape, generator=g, dtype=img.dtype)).sum()
    loss = loss + (sil * torch.randn(sil.shape, generator=g, dtype=sil.dtype)).sum()
    loss.backward()
    grads = {name: p.grad for name, p in params.items()} | {"w2c": w2c.grad}
    return img.detach(), sil.detach(), grads


def assert_grads_close(a, b, rtol):
    for name in a:
        scale = b[name].abs().max().item() + 1e-12
        err = (a[name] - b[name]).abs().max().item()
        assert err <= rtol * scale, f"{name}: max error {err:.3g} vs scale {scale:.3g}"


@pytest.mark.parametrize(
    ("n", "width", "height", "tile", "kwargs"),
    [
        (400, 48, 36, 8, {}),
        (400, 45, 37, 8, {"behind": 40}),  # partial edge tiles, Gaussians behind the camera
        (300, 40, 30, 16, {"anisotropic": True}),
        (800, 64, 48, 4, {}),
    ],
)
def test_tiled_matches_dense(n, width, height, tile, kwargs):
    gm, k = random_scene(n, width, height, seed=n + width, **kwargs)
    settings = RenderSettings(backend="torch", tile_size=tile, chunk_elements=8192)
    img_t, sil_t, g_t = run(gm, k, settings, composite)
    img_d, sil_d, g_d = run(gm, k, settings, "dense")
    assert sil_t.max() > 0.5, "scene should cover the image"
    assert (img_t - img_d).abs().max().item() < FWD_TOL
    assert (sil_t - sil_d).abs().max().item() < FWD_TOL
    assert_grads_close(g_t, g_d, GRAD_RTOL)


def test_custom_backward_matches_autograd_float64():
    gm, k = random_scene(500, 56, 40, seed=9, dtype=torch.float64, behind=20)
    settings = RenderSettings(backend="torch", chunk_elements=4096)
    img_a, sil_a, g_a = run(gm, k, settings, composite)
    img_b, sil_b, g_b = run(gm, k, settings, composite_autograd)
    assert torch.equal(img_a, img_b) or (img_a - img_b).abs().max() < 1e-12
    assert (sil_a - sil_b).abs().max() < 1e-12
    assert_grads_close(g_a, g_b, 1e-9)


def test_one_gaussian_covering_the_whole_image_and_empty_tiles():
    gm, k = random_scene(3, 64, 48, seed=1)
    gm = gm.with_tensors(
        means=torch.tensor([[0.0, 0.0, 2.0], [5.0, 5.0, 2.0], [0.0, 0.0, 3.0]]),
        log_scales=torch.tensor([[1.0], [0.01], [0.05]]).log(),
    )
    settings = RenderSettings(backend="torch")
    img_t, sil_t, g_t = run(gm, k, settings, composite)
    img_d, _, g_d = run(gm, k, settings, "dense")
    assert sil_t.min() > 0.01  # the big Gaussian reaches every pixel
    assert (img_t - img_d).abs().max().item() < FWD_TOL
    assert_grads_close(g_t, g_d, GRAD_RTOL)


def test_no_visible_gaussian_gives_zero_image_and_gradients():
    gm, k = random_scene(10, 32, 24, seed=4, behind=10)
    img, sil, grads = run(gm, k, RenderSettings(backend="torch"), composite)
    assert img.abs().max() == 0 and sil.abs().max() == 0
    assert all(g.abs().max() == 0 for g in grads.values())


def test_render_is_deterministic():
    gm, k = random_scene(500, 48, 36, seed=7)
    a = run(gm, k, RenderSettings(backend="torch"), composite)
    b = run(gm, k, RenderSettings(backend="torch"), composite)
    assert torch.equal(a[0], b[0])
    assert all(torch.equal(a[2][n], b[2][n]) for n in a[2])
