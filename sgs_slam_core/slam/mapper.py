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


class WindowFrame:
    """A frame of the mapping window: its data (or how to make it), estimated pose and loss weight U(t).

    A stored keyframe is decoded on the device each time a mapping step draws it (``deferred``) and
    let go after the step: a window holds up to two dozen keyframes, each ~11 MB decoded at 640x480,
    and a decoding is cheap beside the step that renders the frame.
    """

    def __init__(self, data: FrameTensors, w2c: torch.Tensor, weight: float) -> None:  # w2c [4, 4] on the map's device
        self._data: FrameTensors | None = data
        self._load: Callable[[], FrameTensors] | None = None
        self.has_semantic = data.semantic is not None
        self.w2c = w2c
        self.weight = weight

    @classmethod
    def deferred(
        cls, load: Callable[[], FrameTensors], has_semantic: bool, w2c: torch.Tensor, weight: float
    ) -> WindowFrame:
        """A frame whose data ``load`` makes at each use; ``has_semantic`` says whether it carries semantics."""
        frame = cls.__new__(cls)
        frame._data, frame._load = None, load
        frame.has_semantic, frame.w2c, frame.weight = has_semantic, w2c, weight
        return frame

    def load(self) -> FrameTensors:
        """The frame on the device (decoded now if it is deferred)."""
        if self._data is not None:
            return self._data
        assert self._load is not None
        return self._load()


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
    opt = GaussianOptimizer(gaussians, s, frozen_labels, kernels.mapping.update)
    direct = kernels.direct_mapping(gaussians.isotropic)
    window_semantic = use_semantics and any(wf.has_semantic for wf in window)
    pruned, last, done = 0, float("nan"), 0
    prune_at = set(s.prune_iterations)
    for it in range(s.iterations):
        if between_iterations is not None and not between_iterations():
            break
        wf = window[-1] if it < s.current_frame_steps else window[int(rng.integers(len(window)))]
        semantic = use_semantics and wf.has_semantic
        data = wf.load()
        if direct:  # the same kernels without the autograd graph
            loss = kernels.mapping_step_grads(opt.params, data, wf.w2c, s, semantic, wf.weight, window_semantic)
        else:
            with stage("map.render"):
                out = kernels.render(opt.gaussians(), data.intrinsics, wf.w2c, with_semantics=semantic)
            with stage("map.loss"):
                loss = kernels.mapping_loss(out, data, s, semantic, wf.weight)
            with stage("map.backward"):
                loss.backward()
        with stage("map.step"):
            opt.step()
            if s.max_scale_px is not None:
                opt.cap_scales(wf.w2c, data.intrinsics, s.max_scale_px)
        if it in prune_at:
            with stage("map.prune"):
                pruned += opt.prune(prune_mask(opt.gaussians(), s.prune_opacity, s.prune_scale_ratio * scene_radius))
        done = it + 1
    last = float(loss.detach()) if done else last  # one host sync per window, not per iteration
    return MapResult(opt.result(), MapStats(done, pruned, time.perf_counter() - t0, last))
