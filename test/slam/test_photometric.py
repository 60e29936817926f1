"""The mapping loss's photometric term: the fused CPU kernel and the convolution form against the reference."""

import pytest
import torch

from sgs_slam_core.kernels import build_kernels
from sgs_slam_core.kernels.cpu import losses as cpu_losses
from sgs_slam_core.kernels.cpu.extensions import PHOTOMETRIC
from sgs_slam_core.kernels.photometric import photometric_loss
from sgs_slam_core.render import RenderSettings

fused_only = pytest.mark.skipif(
    not PHOTOMETRIC.is_available(), reason=f"no compiler: {PHOTOMETRIC.unavailable_reason()}"
)


def _pair(h, w, c, dtype, seed):
    g = torch.Generator().manual_seed(seed)
    target = torch.rand(h, w, c, generator=g, dtype=dtype)
    pred = (target + 0.2 * torch.randn(h, w, c, generator=g, dtype=dtype)).clamp(0, 1)  # correlated, like a render
    ignore = torch.rand(h, w, generator=g) < 0.2
    return pred, target, ignore


def _photometric(x, target, ignore, weight, backend):
    """``reference``: PyTorch with the banded blur, ``conv``: with convolutions, ``fused``: the compiled kernel."""
    if backend == "fused":
        return cpu_losses.photometric_loss(x, target, ignore, weight)
    return photometric_loss(x, target, ignore, weight, "conv" if backend == "conv" else "band")


def _loss_and_grad(pred, target, ignore, weight, backend):
    x = pred.clone().requires_grad_(True)
    loss = _photometric(x, target, ignore, weight, backend)
    loss.backward()
    return loss.detach(), x.grad


@pytest.mark.parametrize("backend", ["conv", pytest.param("fused", marks=fused_only)])
@pytest.mark.parametrize(("h", "w", "c"), [(120, 160, 3), (37, 23, 1), (7, 5, 2), (30, 40, 41)])
@pytest.mark.parametrize("weight", [0.2, 0.0, 1.0])
def test_matches_the_reference_in_float64(backend, h, w, c, weight):
    pred, target, ignore = _pair(h, w, c, torch.float64, seed=h * w + c)
    ref_loss, ref_grad = _loss_and_grad(pred, target, ignore, weight, "reference")
    loss, grad = _loss_and_grad(pred, target, ignore, weight, backend)
    assert abs(loss.item() - ref_loss.item()) < 1e-12
    assert (grad - ref_grad).abs().max().item() < 1e-12 * ref_grad.abs().max().item() + 1e-18
    assert ref_grad.abs().max() > 0


@fused_only
def test_float32_within_rounding_of_the_reference():
    pred, target, ignore = _pair(120, 160, 3, torch.float32, seed=3)
    ref_loss, ref_grad = _loss_and_grad(pred, target, ignore, 0.2, "reference")
    loss, grad = _loss_and_grad(pred, target, ignore, 0.2, "fused")
    assert abs(loss.item() - ref_loss.item()) < 1e-6
    assert (grad - ref_grad).abs().max().item() < 1e-5 * ref_grad.abs().max().item()


@fused_only
def test_fused_gradient_against_finite_differences():
    pred, target, _ = _pair(9, 13, 2, torch.float64, seed=5)
    x = pred.clone().requires_grad_(True)
    assert torch.autograd.gradcheck(lambda v: _photometric(v, target, None, 0.3, "fused"), (x,), eps=1e-6)


@fused_only
def test_ignored_pixels_get_no_gradient_and_no_error():
    pred, target, ignore = _pair(40, 30, 3, torch.float64, seed=9)
    _, grad = _loss_and_grad(pred, target, ignore, 0.0, "fused")  # pure L1: only the pixel's own value counts
    assert grad[ignore].abs().max() == 0 and grad[~ignore].abs().min() > 0
    everything = torch.ones(40, 30, dtype=torch.bool)
    assert _loss_and_grad(pred, target, everything, 0.2, "fused")[0].item() == pytest.approx(0.0, abs=1e-15)


@fused_only
def test_fused_result_does_not_depend_on_the_thread_count():
    pred, target, ignore = _pair(120, 160, 3, torch.float32, seed=11)
    before = torch.get_num_threads()
    results = []
    try:
        for threads in (1, 2):
            torch.set_num_threads(threads)
            results.append(_loss_and_grad(pred, target, ignore, 0.2, "fused"))
    finally:
        torch.set_num_threads(before)
    (l1, g1), (l2, g2) = results
    assert torch.equal(l1, l2) and torch.equal(g1, g2)


def test_the_reference_kernels_pick_the_ssim_window_per_device():
    reference = RenderSettings(backend="torch")
    assert build_kernels(reference, torch.device("cpu")).ssim_blur == "band"
    assert build_kernels(reference, torch.device("meta")).ssim_blur == "conv"
    assert build_kernels(RenderSettings(backend="auto"), torch.device("meta")).name == "torch"
