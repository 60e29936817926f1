"""Tracking on the device: masked losses without indexing, best pose and early stop without host reads."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from sgs_slam_core.config import load_config
from sgs_slam_core.config.sections import AdamTrackerSettings, MappingSettings, TrackingSettings
from sgs_slam_core.datasets import open_dataset
from sgs_slam_core.frame_data import FrameTensors
from sgs_slam_core.geometry import se3_exp
from sgs_slam_core.kernels import build_kernels, render
from sgs_slam_core.render import RenderSettings
from sgs_slam_core.render.output import RenderOutput
from sgs_slam_core.slam import tracker as tracker_module
from sgs_slam_core.slam.icp_init import IcpInit
from sgs_slam_core.slam.system import Slam
from sgs_slam_core.slam.tracker import track

from ..conftest import FAST_SLAM
from ..render.scenes import random_scene

SETTINGS = RenderSettings(backend="torch")
TORCH = build_kernels(SETTINGS, "cpu")


def target_frame(n: int = 1500, width: int = 48, height: int = 36) -> tuple[object, FrameTensors]:
    """The scene rendered at the identity pose is the observation, so tracking must come back to it."""
    gm, k = random_scene(n, width, height, seed=3)
    with torch.no_grad():
        out = render(gm, k, torch.eye(4), SETTINGS)
    depth = torch.where(out.silhouette > 0.5, out.depth, 0.0)
    frame = FrameTensors(0, k, out.color, depth, None, out.semantic.clone())
    return gm, frame


@pytest.mark.parametrize("backend", ["torch", "auto"])  # the reference, and the compiled kernels where they build
def test_tracking_loss_matches_indexed_sums_and_gives_no_gradient_outside_the_mask(backend):
    gm, frame = target_frame()
    out = render(gm, frame.intrinsics, se3_exp(torch.tensor([0.01, 0, 0, 0, 0.01, 0])), SETTINGS)
    depth = out.depth.detach().clone()
    depth[3, 4] = float("nan")  # a broken render pixel must not poison the loss or the gradient
    depth.requires_grad_(True)
    out = dataclasses.replace(out, depth=depth)
    s = TrackingSettings(sil_threshold=0.5)
    loss = build_kernels(RenderSettings(backend=backend), "cpu").tracking_loss(out, frame, s, use_semantics=True)
    mask = frame.valid & (out.silhouette.detach() > 0.5) & torch.isfinite(depth.detach())
    expected = (
        (depth - frame.depth).abs()[mask].sum()
        + 0.5 * (out.color - frame.rgb).abs()[mask].sum()
        + 0.05 * (out.semantic - frame.semantic).abs()[mask].sum()
    )
    assert int(loss.pixels) == int(mask.sum()) > 100
    torch.testing.assert_close(loss.total, expected)
    torch.testing.assert_close(loss.depth_residual_m, (depth - frame.depth).abs()[mask].mean().detach())
    loss.total.backward()
    assert torch.isfinite(depth.grad).all() and float(depth.grad[~mask].abs().max()) == 0.0


@pytest.mark.parametrize("backend", ["torch", "auto"])
def test_an_empty_mask_gives_zero_pixels_and_infinite_residual(backend):
    kernels = build_kernels(RenderSettings(backend=backend), "cpu")
    _, frame = target_frame()
    h, w = frame.depth.shape
    out = RenderOutput(torch.zeros(h, w, 3), torch.zeros(h, w), torch.zeros(h, w), torch.zeros(h, w, 3))
    loss = kernels.tracking_loss(out, frame, TrackingSettings(), use_semantics=True)
    assert int(loss.pixels) == 0 and float(loss.total) == 0.0 and loss.depth_residual_m.item() == float("inf")
    no_depth = dataclasses.replace(frame, depth=torch.zeros(h, w))
    assert float(kernels.mapping_loss(out, no_depth, MappingSettings(), False)) >= 0


def adam_settings(**adam: float) -> TrackingSettings:
    """Tracking with these Adam settings over fast rates and 60 steps, on a half-confident mask."""
    steps = {"iterations": 60, "lr_rotation": 4e-3, "lr_translation": 4e-3, **adam}
    return TrackingSettings(sil_threshold=0.5, adam=AdamTrackerSettings(**steps))


def track_checking_every(check_every, settings, gm, frame, start, monkeypatch):
    """``track`` reading its stop test back every ``check_every`` steps (``STOP_CHECK_EVERY``)."""
    with monkeypatch.context() as patch:
        patch.setattr(tracker_module, "STOP_CHECK_EVERY", check_every)
        return track(gm, frame, start, settings, TORCH, True)


def test_reading_the_stop_test_less_often_changes_nothing_but_the_stop_step(monkeypatch):
    gm, frame = target_frame()
    start = se3_exp(torch.tensor([0.02, -0.01, 0.01, 0.01, -0.015, 0.005], dtype=torch.float64)).numpy()
    fixed = [track_checking_every(c, adam_settings(early_stop=False), gm, frame, start, monkeypatch) for c in (1, 7)]
    assert fixed[0].iterations == fixed[1].iterations == 60
    assert np.array_equal(fixed[0].w2c, fixed[1].w2c) and fixed[0].loss == fixed[1].loss
    assert np.abs(fixed[0].w2c - np.eye(4)).max() < 0.2 * np.abs(start - np.eye(4)).max()  # it converged
    every, sparse = (track_checking_every(c, adam_settings(), gm, frame, start, monkeypatch) for c in (1, 7))
    assert every.converged and sparse.converged
    assert sparse.iterations % 7 == 0 and every.iterations <= sparse.iterations  # stops only where it reads
    assert sparse.loss <= every.loss  # more steps never lose the best pose


def test_the_icp_start_runs_after_dropped_frames_only_and_helps_there(tiny_scene, monkeypatch):
    """Lockstep frames start from the motion prediction; a frame after a gap from ICP on depth."""
    tiny = open_dataset(tiny_scene)
    outcomes = []
    start = IcpInit.start

    def spy(self, *args):
        result = start(self, *args)
        outcomes.append(result.outcome)
        return result

    monkeypatch.setattr(IcpInit, "start", spy)
    errors, steps = [], []
    for icp in ("motion.icp_min_gap=1.5", "motion.icp_iterations=[]"):
        frame_to_frame = ("tracking.method=adam", "motion.icp_reference_angle_deg=0")  # against the last frame
        slam = Slam(load_config("synthetic", overrides=[*FAST_SLAM, icp, *frame_to_frame]), tiny.label_table)
        for i in range(4):
            slam.process(tiny[i])
        assert outcomes == []
        step = slam.process(tiny[7])  # frames 4-6 were dropped
        errors.append(np.linalg.norm(step.c2w[:3, 3] - slam._gt_in_map_frame(tiny[7].gt_c2w)[:3, 3]))
        steps.append(step.track.result.iterations)
        if icp.startswith("motion.icp_min_gap"):
            assert len(outcomes) == 1 and outcomes.pop()[0] == 1  # the ICP's pose was used
    assert errors[0] < errors[1] and steps[0] < steps[1]  # measured: 2.1 vs 3.1 cm, 14 vs 30 (the cap) steps


def test_a_newer_frame_waiting_ends_tracking_after_its_minimum_steps(monkeypatch):
    gm, frame = target_frame()
    start = se3_exp(torch.tensor([0.02, -0.01, 0.01, 0.01, -0.015, 0.005], dtype=torch.float64)).numpy()
    monkeypatch.setattr(tracker_module, "MIN_ITERATIONS", 3)
    s = adam_settings()
    asked: list[int] = []
    cut = track(gm, frame, start, s, TORCH, True, newer_frame_waiting=lambda: asked.append(1) or True)
    assert cut.iterations == 3 and not cut.converged and len(asked) == 1  # asked from the minimum on only
    full = track(gm, frame, start, s, TORCH, True, newer_frame_waiting=lambda: False)
    assert full.iterations > 3 and full.loss < cut.loss
    alone = track(gm, frame, start, adam_settings(iterations=3), TORCH, True)
    assert np.array_equal(cut.w2c, alone.w2c)  # the best of the steps made, as a 3-step budget gives
