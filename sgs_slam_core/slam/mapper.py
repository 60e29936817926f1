"""Mapping: optimise the Gaussians on a window of frames at their estimated poses."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from sgs_slam_core.config.sections import MappingSettings
from sgs_slam_core.frame_data import FrameTensors
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.kernels.base import Kernels
from sgs_slam_core.profiling import stage
from sgs_slam_core.slam.optimizer import GaussianOptimizer

__all__ = ["MapResult", "MapStats", "WindowFrame", "map_window", "prune_mask"]


@dataclass
class WindowFrame:
    """A frame of the mapping window: data, estimated pose and loss weight U(t)."""

    data: FrameTensors
    w2c: torch.Tensor  # [4, 4] on the map's device
    weight: float


@dataclass(frozen=True)
class MapStats:
    """What one mapping window did (kept per frame, without the map: a run keeps one map version)."""

    iterations: int
    pruned: int
    time_s: float
    last_loss: float


@dataclass(frozen=True)
class MapResult:
    """The optimised map and what mapping did."""

    gaussians: GaussianMap
    stats: MapStats


def prune_mask(gaussians: GaussianMap, opacity: float, max_scale: float) -> torch.Tensor:  # [N] bool, True = keep
    """Keep Gaussians that are visible enough and not huge."""
    with torch.no_grad():
        op = torch.sigmoid(gaussians.logit_opacities)
        scale = torch.exp(gaussians.log_scales).amax(dim=1)
        return (op >= opacity) & (scale <= max_scale)


def map_window(
    gaussians: GaussianMap,
    window: list[WindowFrame],
    s: MappingSettings,
    kernels: Kernels,
    scene_radius: float,
    use_semantics: bool,
    rng: np.random.Generator,
    frozen_labels: frozenset[int] = frozenset(),
    between_iterations: Callable[[], bool] | None = None,
) -> MapResult:
    """``s.iterations`` Adam steps (fresh optimiser), each on one frame drawn uniformly from the window.

    The first ``s.current_frame_steps`` steps take the window's last frame (the newest) instead.

    Gaussians of ``frozen_labels`` are left exactly as they are. ``between_iterations`` is called
    before each step (live operation); when it returns False the window ends there and the map
    keeps the steps made so far (a newer frame is waiting). Where ``kernels`` have a direct mapping
    step (compiled CPU, isotropic map) each step's gradients come from it, else from autograd.
    """
    t0 = time.perf_counter()
    opt = GaussianOptimizer(gaussians, s, frozen_labels)
    direct = kernels.direct_mapping(gaussians.isotropic)
    window_semantic = use_semantics and any(wf.data.semantic is not None for wf in window)
    pruned, last, done = 0, float("nan"), 0
    prune_at = set(s.prune_iterations)
    for it in range(s.iterations):
        if between_iterations is not None and not between_iterations():
            break
        wf = window[-1] if it < s.current_frame_steps else window[int(rng.integers(len(window)))]
        semantic = use_semantics and wf.data.semantic is not None
        if direct:  # the same kernels without the autograd graph
            loss = kernels.mapping_step_grads(opt.params, wf.data, wf.w2c, s, semantic, wf.weight, window_semantic)
        else:
            with stage("map.render"):
                out = kernels.render(opt.gaussians(), wf.data.intrinsics, wf.w2c, with_semantics=semantic)
            with stage("map.loss"):
                loss = kernels.mapping_loss(out, wf.data, s, semantic, wf.weight)
            with stage("map.backward"):
                loss.backward()
        with stage("map.step"):
            opt.step()
        if it in prune_at:
            with stage("map.prune"):
                pruned += opt.prune(prune_mask(opt.gaussians(), s.prune_opacity, s.prune_scale_ratio * scene_radius))
        done = it + 1
    last = float(loss.detach()) if done else last  # one host sync per window, not per iteration
    return MapResult(opt.result(), MapStats(done, pruned, time.perf_counter() - t0, last))
