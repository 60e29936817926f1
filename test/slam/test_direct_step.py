"""The direct mapping step (kernels called in order, no autograd) against the autograd path, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from sgs_slam_core.config.sections import MappingSettings
from sgs_slam_core.kernels import build_kernels
from sgs_slam_core.kernels.cpu.extensions import EXTENSIONS
from sgs_slam_core.kernels.cpu.kernels import CpuKernels
from sgs_slam_core.render import RenderSettings
from sgs_slam_core.slam import mapper
from sgs_slam_core.slam.optimizer import GaussianOptimizer

from ..render.scenes import unexplained_frame

pytestmark = pytest.mark.skipif(
    not all(ext.is_available() for ext in EXTENSIONS), reason="compiled kernels unavailable"
)

CPU = RenderSettings(backend="cpu")


def _frame(seed: int, ignore: bool) -> tuple:
    return unexplained_frame(seed, ignore, CPU)


@pytest.mark.parametrize("semantic", [True, False])
@pytest.mark.parametrize("ignore", [False, True])
def test_the_direct_gradients_are_autograds(semantic: bool, ignore: bool) -> None:
    gm, data = _frame(3, ignore)
    s, w2c, weight = MappingSettings(), torch.eye(4), 0.8
    kernels = build_kernels(CPU, "cpu")
    ref = GaussianOptimizer(gm, s)
    out = kernels.render(ref.gaussians(), data.intrinsics, w2c, with_semantics=semantic)
    loss = kernels.mapping_loss(out, data, s, semantic, weight)
    loss.backward()
    direct = GaussianOptimizer(gm, s)
    value = kernels.mapping_step_grads(direct.params, data, w2c, s, semantic, weight)
    assert torch.equal(value, loss.detach())
    for name, p in ref.params.items():
        assert torch.equal(direct.params[name].grad, p.grad), name
    assert direct.params["means"].grad.abs().max() > 0
    assert direct.params["semantics"].grad.abs().max() > 0 if semantic else not direct.params["semantics"].grad.any()


@pytest.mark.parametrize("use_semantics", [True, False])
def test_map_window_takes_the_direct_path_with_the_same_result(monkeypatch, use_semantics: bool) -> None:
    gm, data = _frame(4, False)
    window = [mapper.WindowFrame(data, torch.eye(4), 1.0), mapper.WindowFrame(data, torch.eye(4), 0.9)]
    s = MappingSettings(iterations=8, prune_iterations=(3,))
    kernels = build_kernels(CPU, "cpu")
    assert kernels.direct_mapping(gm.isotropic)
    calls = []
    real = CpuKernels.mapping_step_grads
    monkeypatch.setattr(CpuKernels, "mapping_step_grads", lambda *a, **kw: calls.append(1) or real(*a, **kw))
    fast = mapper.map_window(gm, window, s, kernels, 1.0, use_semantics, np.random.default_rng(0))
    assert len(calls) == 8
    monkeypatch.setattr(CpuKernels, "direct_mapping", lambda *a: False)
    slow = mapper.map_window(gm, window, s, kernels, 1.0, use_semantics, np.random.default_rng(0))
    assert len(calls) == 8 and fast.stats.pruned == slow.stats.pruned
    for name in ("means", "log_scales", "logit_opacities", "colors", "semantics", "labels"):
        assert torch.equal(getattr(fast.gaussians, name), getattr(slow.gaussians, name)), name
