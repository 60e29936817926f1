"""The one-node tracking and mapping losses against their references (values and gradients)."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from sgs_slam_core.config.sections import MappingSettings, TrackingSettings
from sgs_slam_core.frame_data import FrameTensors
from sgs_slam_core.kernels.cpu.extensions import PHOTOMETRIC
from sgs_slam_core.kernels.cpu.losses import mapping_loss, tracking_loss
from sgs_slam_core.kernels.losses import mapping_loss_reference, tracking_loss_reference
from sgs_slam_core.render.output import RenderOutput

from ..render.scenes import random_scene

fused_only = pytest.mark.skipif(
    not PHOTOMETRIC.is_available(), reason=f"no compiler: {PHOTOMETRIC.unavailable_reason()}"
)


def _case(seed: int, ignore: bool) -> tuple[RenderOutput, FrameTensors]:
    """A render-like output (a NaN depth pixel, a partial silhouette) and a measured frame."""
    g = torch.Generator().manual_seed(seed)
    _, k = random_scene(10, 40, 30, seed=seed)
    h, w = k.height, k.width
    rgb, sem = torch.rand(h, w, 3, generator=g), torch.rand(h, w, 3, generator=g)
    depth = 1 + torch.rand(h, w, generator=g)
    depth[torch.rand(h, w, generator=g) < 0.1] = 0  # no measurement
    color = (rgb + 0.1 * torch.randn(h, w, 3, generator=g)).requires_grad_(True)
    semantic = (sem + 0.1 * torch.randn(h, w, 3, generator=g)).requires_grad_(True)
    rendered = depth + 0.05 * torch.randn(h, w, generator=g)
    rendered[2, 3] = float("nan")
    rendered.requires_grad_(True)
    sil = torch.rand(h, w, generator=g)
    frame = FrameTensors(0, k, rgb, depth, None, sem, torch.rand(h, w, generator=g) < 0.2 if ignore else None)
    return RenderOutput(color, rendered, sil, semantic), frame


def _value_and_grads(loss: torch.Tensor, out: RenderOutput) -> list[torch.Tensor]:
    grads = torch.autograd.grad(loss, [out.color, out.semantic, out.depth], allow_unused=True, retain_graph=True)
    return [loss.detach()] + [
        g if g is not None else torch.zeros_like(t)
        for g, t in zip(grads, [out.color, out.semantic, out.depth], strict=True)
    ]


@pytest.mark.parametrize("semantics", [True, False])
@pytest.mark.parametrize("ignore", [False, True])
def test_tracking_loss_matches_the_reference(semantics: bool, ignore: bool) -> None:
    out, frame = _case(1, ignore)
    s = TrackingSettings(sil_threshold=0.3)
    fast, ref = tracking_loss(out, frame, s, semantics), tracking_loss_reference(out, frame, s, semantics)
    assert int(fast.pixels) == int(ref.pixels) > 100
    torch.testing.assert_close(fast.depth_residual_m, ref.depth_residual_m)
    for a, b in zip(_value_and_grads(fast.total, out), _value_and_grads(ref.total, out), strict=True):
        torch.testing.assert_close(a, b)
    assert torch.isfinite(torch.autograd.grad(fast.total, out.depth)[0]).all()


@fused_only
@pytest.mark.parametrize("semantics", [True, False])
@pytest.mark.parametrize("ignore", [False, True])
def test_mapping_loss_matches_the_reference(semantics: bool, ignore: bool) -> None:
    out, frame = _case(2, ignore)
    s = MappingSettings()
    fast = mapping_loss(out, frame, s, semantics, scale=0.7)
    ref = 0.7 * mapping_loss_reference(out, frame, s, semantics)
    for a, b in zip(_value_and_grads(fast, out), _value_and_grads(ref, out), strict=True):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-7)
    assert _value_and_grads(fast, out)[1].abs().max() > 0


@fused_only
def test_mapping_loss_without_gradients_and_without_valid_depth() -> None:
    out, frame = _case(3, False)
    out = RenderOutput(*(t.detach() for t in (out.color, out.depth, out.silhouette, out.semantic)))
    frame = dataclasses.replace(frame, depth=torch.zeros_like(frame.depth))
    fast, ref = (
        mapping_loss(out, frame, MappingSettings(), True),
        mapping_loss_reference(out, frame, MappingSettings(), True),
    )
    torch.testing.assert_close(fast, ref)
