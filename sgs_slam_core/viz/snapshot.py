"""What a live viewer shows after each frame, as plain numpy arrays (backend-neutral).

:class:`SnapshotRecorder` turns ``(frame, step, slam)`` into a :class:`Snapshot`: the input images,
the map rendered from the estimated pose (colour, depth, decoded classes), the camera path so far,
the ground-truth path expressed in the map frame, and every ``points_every`` frames the map's
Gaussian centres (subsampled to ``max_points``). Rerun and Foxglove backends only translate it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from sgs_slam_core.frame import Frame
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.slam.system import Slam, StepResult

__all__ = ["MapPoints", "Snapshot", "SnapshotRecorder", "ViewerSettings"]


@dataclass(frozen=True)
class ViewerSettings:
    """How much a live viewer receives.

    Attributes:
        points_every: send the map's points every this many frames (and after the last one).
        max_points: random subset of Gaussian centres beyond this many.
        min_opacity: Gaussians less opaque than this are not sent as points.
        render: render the map from the estimated pose every frame (colour, depth, classes).
    """

    points_every: int = 10
    max_points: int = 200_000
    min_opacity: float = 0.1
    render: bool = True


@dataclass(frozen=True)
class MapPoints:
    """Gaussian centres of the map (map frame)."""

    positions: np.ndarray  # [M, 3] float32 metres
    colors: np.ndarray  # [M, 3] uint8 RGB
    labels: np.ndarray  # [M] int class ids
    total: int  # Gaussians in the map (before opacity filtering and subsampling)


@dataclass(frozen=True)
class Snapshot:
    """Everything one viewer update shows."""

    index: int  # processed-frame counter (0 = first frame)
    stamp_ns: int
    c2w: np.ndarray  # [4, 4] estimated camera-to-map pose
    intrinsics: Intrinsics
    rgb: np.ndarray  # [H, W, 3] uint8 input colour
    depth: np.ndarray  # [H, W] float32 input depth (m, 0 = none)
    labels: np.ndarray | None  # [H, W] input class ids
    render_rgb: np.ndarray | None  # [H, W, 3] uint8
    render_depth: np.ndarray | None  # [H, W] float32 m (sum of w*z, as the renderer)
    render_labels: np.ndarray | None  # [H, W] decoded class ids, 0 where the map is transparent
    path: np.ndarray  # [T, 3] estimated camera centres so far (map frame)
    gt_path: np.ndarray | None  # [T', 3] ground-truth centres in the map frame
    points: MapPoints | None  # None when not due this frame
    num_gaussians: int
    track_ms: float
    map_ms: float
    tracking_failed: bool


class SnapshotRecorder:
    """Accumulates the camera paths and builds a :class:`Snapshot` per processed frame."""

    def __init__(self, settings: ViewerSettings = ViewerSettings()) -> None:
        self.settings = settings
        self._path: list[np.ndarray] = []
        self._gt_path: list[np.ndarray] = []
        self._gt_to_map: np.ndarray | None = None  # [4, 4] dataset world -> map frame
        self._points_sent_at = -settings.points_every  # the first frame sends the map

    def capture(self, frame: Frame, step: StepResult, slam: Slam, force_points: bool = False) -> Snapshot:
        """The snapshot after ``step`` (``force_points``: include the map's points regardless of the rate)."""
        self._path.append(step.c2w[:3, 3].astype(np.float64))
        if frame.gt_c2w is not None:
            if self._gt_to_map is None:  # the first frame with ground truth anchors it to its estimate
                self._gt_to_map = step.c2w @ np.linalg.inv(frame.gt_c2w)
            self._gt_path.append((self._gt_to_map @ frame.gt_c2w)[:3, 3])
        render_rgb = render_depth = render_labels = None
        if self.settings.render and slam.num_gaussians and slam.intrinsics is not None:
            render_rgb, render_depth, render_labels = self._render(slam, step.c2w, frame.labels is not None)
        due = force_points or step.index - self._points_sent_at >= self.settings.points_every
        points = self.map_points(slam) if due else None
        if points is not None:
            self._points_sent_at = step.index
        return Snapshot(
            index=step.index,
            stamp_ns=step.track.stamp_ns,
            c2w=step.c2w,
            intrinsics=frame.intrinsics,
            rgb=frame.rgb,
            depth=frame.depth,
            labels=frame.labels,
            render_rgb=render_rgb,
            render_depth=render_depth,
            render_labels=render_labels,
            path=np.stack(self._path),
            gt_path=np.stack(self._gt_path) if self._gt_path else None,
            points=points,
            num_gaussians=step.num_gaussians,
            track_ms=1e3 * step.track.time_s,
            map_ms=1e3 * step.map.time_s,
            tracking_failed=step.track.failed,
        )

    @staticmethod
    def _render(slam: Slam, c2w: np.ndarray, semantic: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        with_sem = semantic and slam.codec.num_channels > 0
        out = slam.render_view(c2w, with_semantics=with_sem)
        rgb = (out.color.clamp(0, 1) * 255).round().to(torch.uint8).cpu().numpy()
        depth = torch.nan_to_num(out.depth, nan=0.0, posinf=0.0).float().cpu().numpy()
        labels = None
        if with_sem:
            decoded = slam.decode_image(out.semantic)
            labels = torch.where(out.silhouette > 0.5, decoded, torch.zeros_like(decoded)).cpu().numpy()
        return rgb, depth, labels

    def map_points(self, slam: Slam) -> MapPoints | None:
        """The map's opaque Gaussian centres, subsampled deterministically; None for an empty map."""
        g = slam.gaussians
        if len(g) == 0:
            return None
        keep = torch.sigmoid(g.logit_opacities) >= self.settings.min_opacity  # [N]
        idx = torch.nonzero(keep).squeeze(1)
        if idx.numel() > self.settings.max_points:
            gen = torch.Generator(device="cpu").manual_seed(0)
            pick = torch.randperm(idx.numel(), generator=gen)[: self.settings.max_points].to(idx.device)
            idx = idx[pick.sort().values]
        return MapPoints(
            positions=g.means[idx].detach().float().cpu().numpy(),
            colors=(g.colors[idx].detach().clamp(0, 1) * 255).round().to(torch.uint8).cpu().numpy(),
            labels=g.labels[idx].cpu().numpy(),
            total=len(g),
        )
