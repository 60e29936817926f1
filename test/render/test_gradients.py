"""Float64 finite-difference checks of every gradient the SLAM optimises."""

import pytest
import torch

from sgs_slam_core.geometry import se3_exp
from sgs_slam_core.kernels import render
from sgs_slam_core.render import RenderSettings

from .scenes import random_scene

SETTINGS = RenderSettings(backend="torch")


def scalar_loss(gm, k, w2c):
    out = render(gm, k, w2c, SETTINGS)
    g = torch.Generator().manual_seed(11)
    weights = [
        torch.randn(t.shape, generator=g, dtype=t.dtype) for t in (out.color, out.depth, out.silhouette, out.semantic)
    ]
    return sum(
        (t * w).sum() for t, w in zip((out.color, out.depth, out.silhouette, out.semantic), weights, strict=True)
    )


def check(fn, tensor: torch.Tensor, entries: int = 8, eps: float = 1e-6, seed: int = 0) -> None:
    """Autograd vs central differences on a few random entries of ``tensor``."""
    x = tensor.detach().clone().requires_grad_(True)
    fn(x).backward()
    analytic = x.grad.reshape(-1)
    g = torch.Generator().manual_seed(seed)
    picks = torch.randperm(x.numel(), generator=g)[:entries]
    flat = x.detach().reshape(-1)
    for i in picks.tolist():
        plus, minus = flat.clone(), flat.clone()
        plus[i] += eps
        minus[i] -= eps
        numeric = (fn(plus.reshape(x.shape)) - fn(minus.reshape(x.shape))).item() / (2 * eps)
        assert analytic[i].item() == pytest.approx(numeric, rel=1e-5, abs=1e-6), f"entry {i}"


@pytest.fixture(scope="module")
def scene():
    return random_scene(60, 24, 18, seed=3, dtype=torch.float64)


@pytest.mark.parametrize("field", ["means", "log_scales", "logit_opacities", "colors", "semantics"])
def test_gaussian_parameter_gradients(scene, field):
    gm, k = scene
    w2c = torch.eye(4, dtype=torch.float64)
    check(lambda x: scalar_loss(gm.with_tensors(**{field: x}), k, w2c), getattr(gm, field))


@pytest.mark.parametrize(("part", "index"), [("translation", slice(0, 3)), ("rotation", slice(3, 6))])
def test_pose_gradients(scene, part, index):
    gm, k = scene
    w2c0 = se3_exp(torch.tensor([0.05, -0.02, 0.1, 0.02, -0.03, 0.01], dtype=torch.float64))

    def loss(xi3):
        xi = torch.zeros(6, dtype=torch.float64)
        xi = xi.index_put((torch.arange(6)[index],), xi3)
        return scalar_loss(gm, k, se3_exp(xi) @ w2c0)

    x0 = torch.zeros(3, dtype=torch.float64)
    check(loss, x0, entries=3)
    x = x0.clone().requires_grad_(True)
    loss(x).backward()
    assert x.grad.abs().max() > 1e-3, f"{part} gradient is zero"


def test_anisotropic_gradients():
    gm, k = random_scene(40, 20, 16, seed=5, dtype=torch.float64, anisotropic=True)
    w2c = se3_exp(torch.tensor([0.0, 0.0, 0.0, 0.03, 0.02, -0.01], dtype=torch.float64))
    for field in ("means", "log_scales", "quats"):
        check(lambda x, f=field: scalar_loss(gm.with_tensors(**{f: x}), k, w2c), getattr(gm, field), entries=5)
