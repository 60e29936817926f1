"""The mapping loss and Adam's update through ``torch.compile`` (``render.compile``) against their eager code."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from sgs_slam_core.config import load_config
from sgs_slam_core.config.sections import MappingSettings
from sgs_slam_core.datasets import open_dataset
from sgs_slam_core.kernels import build_kernels, render
from sgs_slam_core.kernels.base import MappingKernels
from sgs_slam_core.kernels.compiled import compiled_mapping_kernels
from sgs_slam_core.kernels.losses import mapping_inputs, mapping_loss_of, mapping_loss_reference
from sgs_slam_core.render import RenderSettings
from sgs_slam_core.slam import mapper
from sgs_slam_core.slam.system import Slam

from ..conftest import FAST_SLAM
from ..render.scenes import unexplained_frame

COMPILED = compiled_mapping_kernels()
TORCH = RenderSettings(backend="torch")


def _frame(seed: int, ignore: bool) -> tuple:
    return unexplained_frame(seed, ignore, TORCH, n=400, width=48, height=36)


@pytest.mark.parametrize(("semantic", "ignore", "blur"), [(True, False, "band"), (False, True, "conv")])
def test_the_compiled_loss_and_its_gradients_match_the_eager_loss(semantic: bool, ignore: bool, blur: str) -> None:
    gm, data = _frame(1, ignore)
    s = MappingSettings()
    with torch.no_grad():
        out = render(gm, data.intrinsics, torch.eye(4), TORCH)
    target, weights = mapping_inputs(data, s, semantic)
    assert (target.semantic is not None) == semantic and (target.ignore is not None) == ignore
    results = []
    for loss_of in (mapping_loss_of, COMPILED.loss):
        images = [t.detach().clone().requires_grad_(True) for t in (out.color, out.depth, out.semantic)]
        loss = loss_of(*images, target, weights, blur)
        loss.backward()
        results.append((loss.detach(), [t.grad for t in images]))
    (slow, slow_grads), (fast, fast_grads) = results
    torch.testing.assert_close(fast, slow, rtol=1e-5, atol=0.0)
    torch.testing.assert_close(slow, mapping_loss_reference(out, data, s, semantic, blur))
    if not semantic:  # the rendered semantics are not in the loss
        assert slow_grads.pop() is None and fast_grads.pop() is None
    for fast_grad, slow_grad in zip(fast_grads, slow_grads, strict=True):
        assert slow_grad.abs().max() > 0
        torch.testing.assert_close(fast_grad, slow_grad, rtol=1e-4, atol=1e-5 * float(slow_grad.abs().max()))


def test_a_window_mapped_with_the_compiled_parts_ends_where_the_eager_one_does() -> None:
    gm, data = _frame(2, False)
    window = [mapper.WindowFrame(data, torch.eye(4), 1.0), mapper.WindowFrame(data, torch.eye(4), 0.9)]
    s = MappingSettings(iterations=6, prune_iterations=(3,))
    eager = build_kernels(TORCH, "cpu")
    compiled = build_kernels(RenderSettings(backend="torch", compile=True), "cpu")
    assert eager.mapping == MappingKernels() and compiled.mapping.loss is not None and compiled.mapping.update
    slow = mapper.map_window(gm, window, s, eager, 1.0, True, np.random.default_rng(0))
    fast = mapper.map_window(gm, window, s, compiled, 1.0, True, np.random.default_rng(0))
    assert fast.stats.pruned == slow.stats.pruned and fast.stats.iterations == 6
    moved = (slow.gaussians.means - gm.means).abs().max()
    assert moved > 1e-4  # the steps moved the map
    for name in ("means", "log_scales", "logit_opacities", "colors", "semantics"):
        a, b = getattr(fast.gaussians, name), getattr(slow.gaussians, name)
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5, msg=name)


def test_prepare_compiles_on_a_sample_frame_and_leaves_the_slam_as_it_was(tiny_scene) -> None:
    dataset = open_dataset(tiny_scene)
    config = load_config("synthetic", overrides=[*FAST_SLAM, "render.backend=torch", "render.compile=true"])
    slam = Slam(config, dataset.label_table)
    lines: list[str] = []
    traced = torch._dynamo.utils.counters["frames"]["ok"]
    slam.prepare(lines.append, dataset[0])
    assert lines == ["render.compile: compiling for 64x48 (seconds; cached on disk for later runs)"]
    assert torch._dynamo.utils.counters["frames"]["ok"] > traced  # graphs were traced (or found cached)
    assert not slam.trajectory and len(slam.gaussians) == 0 and len(slam.keyframes) == 0
    steps = [slam.process(dataset[i]) for i in range(3)]
    assert not any(step.track.failed for step in steps) and steps[0].index == 0
