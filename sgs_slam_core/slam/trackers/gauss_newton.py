"""Frame-to-model tracking by Gauss-Newton: render the map once at the prediction, then solve.

The frame's points are aligned to the rendering's vertices and normals (point-to-plane, projective
association) and its intensity and semantic features to the rendered ones through their image
gradients, coarse to fine, with analytic Jacobians (``geometry.icp``). No autograd runs through
the renderer, every step has a fixed shape, and the host reads the result once.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace
from typing import Literal

import numpy as np
import torch
from torch import Tensor

from sgs_slam_core.config.sections import TrackingSettings
from sgs_slam_core.frame_data import FrameTensors
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.geometry.icp import (
    IcpLevel,
    Observations,
    align_device,
    channel_pyramid,
    icp_pyramid,
    refine_device,
    source_channels,
)
from sgs_slam_core.geometry.se3 import se3_inverse
from sgs_slam_core.kernels.base import Kernels
from sgs_slam_core.profiling import stage
from sgs_slam_core.render.output import RenderOutput
from sgs_slam_core.slam.features import Landmarks
from sgs_slam_core.slam.pose import read_pose
from sgs_slam_core.slam.tracker import TrackRendering, TrackResult, track

__all__ = ["GaussNewtonTracker"]

_LUMA = (0.299, 0.587, 0.114)  # ITU-R BT.601 weights of R, G, B in the intensity
# Times the map is rendered and the frame aligned to that rendering, each from the last result; one
# more render judges the result (the Adam tracker's loss, for the guard). One: with the judging
# render, two renders a frame, so live runs keep up with a camera (``live.overlay``).
RENDERS = 1
# The colour term aligns the frame's ``intensity`` (one channel, BT.601 luma) or ``rgb`` (three).
COLOR_CHANNELS: Literal["intensity", "rgb"] = "intensity"
# The finest this many pyramid levels carry the intensity and semantic terms (0 = every level);
# coarser levels align depth alone, which converges from farther.
PHOTOMETRIC_LEVELS = 1
# Steps of the Adam tracker after the solve (its loss, keeping the best evaluated pose, so never worse
# than the solve by that loss); 0 = none: each would cost one more render of the map.
ADAM_STEPS = 0
# Those steps' learning rates as a fraction of ``tracking.adam.lr_*``: the solve starts them near the
# optimum, where the full rates overshoot.
ADAM_LR_SCALE = 0.25
# The frame size (pixels) at which a feature match weighs ``gauss_newton.feature_weight`` dense pixels.
FEATURE_WEIGHT_PIXELS = 160 * 120


class GaussNewtonTracker:
    """Renders the map ``RENDERS`` times per frame and solves for the pose by Gauss-Newton.

    The result is judged by the Adam tracker's loss at one more rendering, so the failure guard sees
    the same quantities whichever tracker runs; ``ADAM_STEPS`` > 0 polishes it with
    that many Adam steps instead. With no steps at any level the start (the motion model's
    prediction) is judged at its one rendering.
    """

    def __init__(self, settings: TrackingSettings, kernels: Kernels) -> None:
        self.settings, self.kernels = settings, kernels
        self.gn = settings.gauss_newton
        self.icp = self.gn.icp

    def track(
        self,
        gaussians: GaussianMap,
        frame: FrameTensors,
        init_w2c: np.ndarray | Tensor,  # [4, 4] float64
        use_semantics: bool,
        newer_frame_waiting: Callable[[], bool] | None = None,
        landmarks: Landmarks | None = None,
        also_read: Tensor | None = None,  # [K]
    ) -> TrackResult:
        """Gauss-Newton from ``init_w2c`` against the map rendered there.

        ``newer_frame_waiting`` matters only to the optional Adam steps: the solve itself costs a
        fixed, small number of renders. ``landmarks`` join the finest level's steps as reprojection
        terms, each weighing ``gauss_newton.feature_weight`` pixels (0: not used). The pose, the
        start and ``also_read`` come back to the host in one read at the end.
        """
        t0 = time.perf_counter()
        fixed = gaussians.detach()
        semantic = use_semantics and frame.semantic is not None and self.gn.semantic_scale_m > 0
        init = torch.as_tensor(init_w2c, dtype=torch.float64, device=fixed.device)
        steps = sum(self.icp.steps_for(frame.intrinsics.width)) * RENDERS
        if steps == 0 and ADAM_STEPS == 0:  # no solve: the start, judged at its own rendering
            with stage("track.render"), torch.no_grad():
                start = self.kernels.render(fixed, frame.intrinsics, init.float(), with_semantics=use_semantics)
            return self._judge(gaussians, frame, (init, start), use_semantics, (init, also_read), 0, t0, at_start=True)
        landmarks = landmarks if landmarks is not None and len(landmarks) and self.gn.feature_weight > 0 else None
        w2c, start = self._solve(fixed, frame, init, semantic, use_semantics and self.gn.keep_start, landmarks)
        if ADAM_STEPS > 0:
            scale = ADAM_LR_SCALE
            a = self.settings.adam
            polish = replace(
                a,
                iterations=ADAM_STEPS,
                lr_rotation=a.lr_rotation * scale,
                lr_translation=a.lr_translation * scale,
            )
            adam = replace(self.settings, adam=polish)
            solved, read = read_pose(w2c, also_read)
            polished = track(gaussians, frame, solved, adam, self.kernels, use_semantics, newer_frame_waiting)
            return replace(
                polished,
                iterations=steps + polished.iterations,
                time_s=time.perf_counter() - t0,
                renders=RENDERS + polished.iterations,
                also_read=read,
            )
        return self._judge(gaussians, frame, (w2c, start), use_semantics, (init, also_read), steps, t0)

    def _solve(
        self,
        gaussians: GaussianMap,
        frame: FrameTensors,
        w2c: Tensor,
        semantic: bool,
        judged_semantics: bool,
        landmarks: Landmarks | None,
    ) -> tuple[Tensor, RenderOutput]:
        """The aligned world-to-camera pose [4, 4] float64 (on the device), and the rendering at the start.

        ``semantic``: the alignment has a semantic term; ``judged_semantics``: the start's rendering
        also carries the semantic channels, for the tracking loss that judges it.
        """
        k = frame.intrinsics
        levels = len(self.icp.steps_for(k.width))
        depth = torch.where(frame.valid, frame.depth, 0.0)
        channels = self._channels(frame.rgb, frame.semantic if semantic else None)
        sources = None if channels is None else self._photometric(source_channels(channels, self._kept(levels)), levels)
        eye = torch.eye(4, dtype=torch.float64, device=w2c.device)
        rendered: list[RenderOutput] = []
        for i in range(RENDERS):
            with_semantics = semantic or (i == 0 and judged_semantics)
            with stage("track.render"):
                rendered.append(self.kernels.render(gaussians, k, w2c.float(), with_semantics=with_semantics))
            with stage("track.solve"):
                reference = self._reference(rendered[-1], k, levels, semantic)
                aligned = self._align(depth, k, reference, eye, sources, self._observations(landmarks, w2c, k))
                w2c = se3_inverse(aligned) @ w2c  # the frame's camera -> the rendered camera
        return w2c, rendered[0]  # RENDERS >= 1

    def _align(
        self,
        depth: Tensor,  # [H, W] m, 0 = invalid
        k: Intrinsics,
        reference: list[IcpLevel],
        start: Tensor,  # [4, 4] float64
        sources: list[Tensor | None] | None,
        observations: Observations | None,
    ) -> Tensor:  # [4, 4] float64 the frame's camera -> the rendered camera
        """The alignment, checked against its start unless :meth:`_judge` does (``keep_start``).

        Not checked either with ``observations``: the feature matches hold the pose where the start
        was right.
        """
        if self.gn.keep_start or observations is not None:
            return refine_device(depth, k, reference, start, self.icp, sources, self.kernels.icp, observations)
        return align_device(depth, k, reference, start, self.icp, sources, self.kernels.icp).src_to_ref

    def _observations(
        self, landmarks: Landmarks | None, w2c: Tensor, k: Intrinsics
    ) -> Observations | None:  # w2c [4, 4]
        """The landmarks in the camera frame of the rendering at ``w2c``, as the alignment's observations.

        The dense terms are a sum over the frame's pixels, so a match weighs ``feature_weight`` pixels
        of a 160x120 frame times the frame's pixel count over that one's: the same share at any size.
        """
        if landmarks is None:
            return None
        weight = self.gn.feature_weight * k.width * k.height / FEATURE_WEIGHT_PIXELS
        points = torch.as_tensor(landmarks.points, dtype=torch.float64, device=w2c.device)
        pixels = torch.as_tensor(landmarks.pixels, dtype=torch.float64, device=w2c.device)
        camera = points @ w2c[:3, :3].T + w2c[:3, 3]
        return Observations(camera, pixels, weight, landmarks.huber_px)

    def _reference(self, out: RenderOutput, k: Intrinsics, levels: int, semantic: bool) -> list[IcpLevel]:
        """The rendering as the alignment's reference, where the silhouette is confident.

        Depth and colour stay unnormalised by the silhouette, as the mapping loss fits them to the
        measurements (normalising moved the room's poses by millimetres).
        """
        confident = (out.silhouette > self.settings.sil_threshold) & torch.isfinite(out.depth)
        depth = torch.where(confident, out.depth, 0.0)
        geometry = icp_pyramid(depth, k, levels, self.kernels.icp.level)
        channels = self._channels(out.color, out.semantic if semantic else None)
        if channels is None:
            return geometry
        images = self._photometric(channel_pyramid(channels, confident, self._kept(levels)), levels)
        return [
            level if image is None else level.with_channels(image)
            for level, image in zip(geometry, images, strict=True)
        ]

    def _kept(self, levels: int) -> int:
        """How many of the finest of ``levels`` pyramid levels carry the photometric terms."""
        return min(PHOTOMETRIC_LEVELS or levels, levels)

    def _photometric(self, finest: list[Tensor], levels: int) -> list[Tensor | None]:
        """Per pyramid level (coarsest first), its channels where it carries the photometric terms, else None.

        ``finest``: the channel pyramid of the :meth:`_kept` finest levels only; a pyramid is built
        from the full image down, so these are the same levels a full pyramid would end with.
        """
        return [None] * (levels - len(finest)) + finest

    def _channels(self, rgb: Tensor, semantic: Tensor | None) -> Tensor | None:  # [H, W, 3], [H, W, S] -> [H, W, C]
        """Intensity and semantic features scaled to metres of residual; None when both terms are off."""
        parts = []
        if self.gn.color_scale_m > 0 and COLOR_CHANNELS == "rgb":
            parts.append(rgb * self.gn.color_scale_m)
        elif self.gn.color_scale_m > 0:
            luma = torch.tensor(_LUMA, dtype=rgb.dtype, device=rgb.device) * self.gn.color_scale_m
            parts.append((rgb @ luma)[..., None])
        if semantic is not None:
            parts.append(semantic * self.gn.semantic_scale_m)
        if len(parts) < 2:
            return parts[0] if parts else None
        return torch.cat(parts, dim=-1)

    def _judge(
        self,
        gaussians: GaussianMap,
        frame: FrameTensors,
        solved: tuple[Tensor, RenderOutput],  # the solved w2c [4, 4] float64, the rendering at the start
        use_semantics: bool,
        started: tuple[Tensor, Tensor | None],  # the start w2c [4, 4] float64, the caller's values to read [K]
        steps: int,
        t0: float,
        at_start: bool = False,
    ) -> TrackResult:
        """The tracking loss at the solved pose and at the start, read back with both poses in one host read.

        With ``keep_start`` the solve is kept unless the start's loss is lower (the Adam tracker, too,
        keeps its best evaluated pose, the start included); without, the start's loss is not
        computed. ``at_start``: there was no solve, the pose is the start and ``solved``'s rendering
        is at it, judged alone. The rendering at the kept pose goes with the result, and
        densification reuses it while ``gaussians`` is the map.
        """
        w2c, start = solved
        if at_start:
            out, keep_start, renders = start, False, 1
        else:
            with stage("track.render"), torch.no_grad():
                out = self.kernels.render(gaussians, frame.intrinsics, w2c.float(), with_semantics=use_semantics)
            keep_start, renders = self.gn.keep_start, RENDERS + 1
        with stage("track.loss"):
            judged = (out, start) if keep_start else (out,)
            stats = torch.cat([self._loss_stats(rendered, frame, use_semantics) for rendered in judged])
        init, also_read = started
        extra = [] if also_read is None else [also_read.reshape(-1).double()]
        values = torch.cat([stats, w2c.reshape(-1), init.reshape(-1), *extra]).cpu().numpy()
        n = len(stats)
        pose, init_w2c = values[n : n + 16].reshape(4, 4), values[n + 16 : n + 32].reshape(4, 4)
        read = None if also_read is None else values[n + 32 :]
        if keep_start and values[4] > 0 and (values[1] == 0 or values[3] < values[0]):  # the start is better
            values, pose, out = values[3:], init_w2c.copy(), start
        value, pixels, residual = (float(v) for v in values[:3])
        if pixels == 0:  # nothing explained at either pose: keep the prediction, as the Adam tracker does
            inf, elapsed = float("inf"), time.perf_counter() - t0
            return TrackResult(init_w2c, steps, False, inf, 0.0, inf, 0.0, elapsed, renders, None, read)
        return TrackResult(
            pose,
            steps,
            True,
            value,
            value / pixels,
            residual,
            pixels / frame.depth.numel(),
            time.perf_counter() - t0,
            renders,
            TrackRendering(gaussians, out),
            read,
        )

    def _loss_stats(self, out: RenderOutput, frame: FrameTensors, use_semantics: bool) -> Tensor:
        """[3] float64: the tracking loss at ``out``, its pixel count and mean depth residual (m)."""
        loss = self.kernels.tracking_loss(out, frame, self.settings, use_semantics)
        return torch.stack(
            [loss.total.detach().double(), loss.pixels.double(), loss.depth_residual_m.detach().double()]
        )
