"""FusedAdam, with each of its updates, against torch.optim.Adam (the reference: per-tensor learning rates)."""

from __future__ import annotations

import pytest
import torch

from sgs_slam_core.kernels.adam import adam_update
from sgs_slam_core.kernels.compiled import CompiledFunction
from sgs_slam_core.slam.adam import FusedAdam

UPDATES = {"fused": None, "written out": adam_update, "compiled": CompiledFunction(adam_update, dynamic=True)}


@pytest.mark.parametrize("update", UPDATES)
@pytest.mark.parametrize("eps", [1e-8, 1e-15])
def test_fused_adam_matches_torch_adam_with_per_tensor_rates(eps: float, update: str) -> None:
    gen = torch.Generator().manual_seed(0)
    shapes = {"a": (50, 3), "b": (50,), "c": (4,)}
    lrs = {"a": 1e-3, "b": 5e-2, "c": 2e-3}
    start = {n: torch.randn(s, generator=gen) for n, s in shapes.items()}
    ours = {n: t.clone().requires_grad_(True) for n, t in start.items()}
    ref = {n: t.clone().requires_grad_(True) for n, t in start.items()}
    adam = FusedAdam(ours, lrs, eps=eps, update=UPDATES[update])
    torch_adam = torch.optim.Adam([{"params": [ref[n]], "lr": lrs[n]} for n in shapes], eps=eps, foreach=False)
    for it in range(12):
        grads = {n: torch.randn(s, generator=gen) for n, s in shapes.items()}
        for n in shapes:
            if not (n == "c" and it % 3 == 0):  # a tensor without a gradient is skipped, as torch does
                ours[n].grad, ref[n].grad = grads[n].clone(), grads[n].clone()
        adam.step()
        torch_adam.step()
        torch_adam.zero_grad(set_to_none=True)
        assert all(ours[n].grad is None for n in shapes)
    for n in shapes:
        torch.testing.assert_close(ours[n].detach(), ref[n].detach(), rtol=1e-5, atol=1e-6)
        assert int(adam.state[n].step) == int(torch_adam.state[ref[n]]["step"])


def test_replace_keeps_the_moments_of_the_kept_rows() -> None:
    params = {"a": torch.ones(5, 2, requires_grad=True)}
    adam = FusedAdam(params, {"a": 0.1})
    params["a"].grad = torch.arange(10.0).view(5, 2)
    adam.step()
    keep = torch.tensor([True, False, True, True, False])
    moments = adam.state["a"].exp_avg.clone()
    adam.replace("a", params["a"].detach()[keep].clone().requires_grad_(True), keep)
    assert params["a"].shape == (3, 2) and torch.equal(adam.state["a"].exp_avg, moments[keep])
    adam.replace("a", torch.zeros(1, 2, requires_grad=True))  # no rows: fresh moments
    assert "a" not in adam.state
