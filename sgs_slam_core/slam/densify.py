"""Gaussians from pixels: first-frame initialisation and densification of unexplained pixels."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor

from sgs_slam_core.config.sections import DensifySettings
from sgs_slam_core.frame import Frame
from sgs_slam_core.frame_data import FrameTensors, resize_arrays
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.geometry.camera import backproject
from sgs_slam_core.geometry.se3 import se3_inverse
from sgs_slam_core.kernels.base import Kernels
from sgs_slam_core.render.output import RenderOutput
from sgs_slam_core.semantics import SemanticCodec
from sgs_slam_core.slam.edits import EditLocks

__all__ = ["DensifyMask", "densify_frame", "densify_mask", "gaussians_from_pixels", "over_budget",
           "shallowest", "spaced"]  # fmt: skip

_CELL_BASE_M = 1e-3  # spacing cells are this times a power of two (m)


class DensifyMask(NamedTuple):
    """The pixels needing new Gaussians, by reason ([H, W] bool each, disjoint)."""

    empty: Tensor  # valid pixels the map leaves uncovered (silhouette below the threshold)
    in_front: Tensor  # valid covered pixels measured in front of everything rendered around them
    at_edge: Tensor  # valid covered pixels measured in front of their own rendered depth only

    def union(self) -> Tensor:  # [H, W] bool
        """Pixels flagged for any reason."""
        return self.empty | self.in_front | self.at_edge


def densify_mask(out: RenderOutput, frame: FrameTensors, s: DensifySettings) -> DensifyMask:
    """Pixels needing new Gaussians: silhouette below threshold, or new geometry in front.

    The depth test follows the reference: rendered depth greater than measured and the absolute
    error above ``depth_error_factor`` x the median error over all pixels (invalid ones as 0).
    A flagged pixel counts as ``at_edge`` when, within ``front_window``, some pixel renders a depth
    that is not that far behind the measurement: a mapped edge renders a blend of its foreground
    and background, deeper than the measured foreground, while a neighbour renders the foreground.
    """
    sil, depth = out.silhouette.detach(), out.depth.detach()
    valid = frame.valid
    err = torch.where(valid, (frame.depth - depth).abs(), torch.zeros_like(depth))
    threshold = s.depth_error_factor * err.median()
    flagged = valid & (depth > frame.depth) & (err > threshold) & ~(sil < s.sil_threshold)
    if s.front_window > 1:
        in_front = flagged & (shallowest(depth, s.front_window) - frame.depth > threshold)
    else:
        in_front = flagged
    return DensifyMask(valid & (sil < s.sil_threshold), in_front, flagged & ~in_front)


def shallowest(depth: Tensor, window: int) -> Tensor:  # [H, W] -> [H, W]
    """The least depth within a ``window`` x ``window`` neighbourhood of each pixel (odd window).

    The minimum of shifted copies, rows then columns: the values of a min-pool
    (:func:`shallowest_reference`) without ``max_pool2d``'s slow CPU kernel, on every densified frame.
    """
    r = window // 2
    if r == 0:
        return depth
    h, w = depth.shape
    padded = torch.nn.functional.pad(depth[None], (r, r, r, r), value=math.inf)[0]  # [H + 2r, W + 2r]
    rows = padded[:, :w]
    for i in range(1, 2 * r + 1):
        rows = torch.minimum(rows, padded[:, i : i + w])
    out = rows[:h]
    for j in range(1, 2 * r + 1):
        out = torch.minimum(out, rows[j : j + h])
    return out


def shallowest_reference(depth: Tensor, window: int) -> Tensor:  # [H, W] -> [H, W]
    """:func:`shallowest` as a min-pool (the reference its tests compare with)."""
    return -torch.nn.functional.max_pool2d(-depth[None, None], window, stride=1, padding=window // 2)[0, 0]


def gaussians_from_pixels(
    frame: FrameTensors,
    c2w: Tensor,  # [4, 4]
    mask: Tensor,  # [H, W] bool
    num_semantic: int,
    settings: DensifySettings,
    anisotropic: bool = False,
    generator: torch.Generator | None = None,
    existing: GaussianMap | None = None,
) -> GaussianMap:
    """One Gaussian per masked pixel, initialised from that pixel.

    Centre back-projected with ``c2w``, radius = depth / mean focal length (one pixel's footprint),
    colour, semantic target and class id from the pixel. With ``settings.min_spacing`` a pixel
    whose spacing cell already holds a Gaussian of ``existing`` (or an earlier pixel) adds none.
    """
    k = frame.intrinsics
    depth = torch.where(mask, frame.depth, torch.zeros_like(frame.depth))
    points, valid = backproject(depth, k, c2w)
    idx = torch.nonzero(valid.reshape(-1)).squeeze(1)
    if settings.min_spacing is not None:
        keep = spaced(points, depth.reshape(-1)[idx] / (0.5 * (k.fx + k.fy)), existing, settings.min_spacing)
        idx, points = idx[keep], points[keep]
    if settings.max_new_per_frame is not None and idx.numel() > settings.max_new_per_frame:
        on = generator.device if generator is not None else idx.device  # the generator's device decides the draw
        pick = torch.randperm(idx.numel(), generator=generator, device=on)[: settings.max_new_per_frame].to(idx.device)
        idx, points = idx[pick], points[pick]
    n = idx.numel()
    device, dtype = frame.rgb.device, frame.rgb.dtype
    radius = depth.reshape(-1)[idx] / (0.5 * (k.fx + k.fy))
    colors = frame.rgb.reshape(-1, 3)[idx]
    if frame.semantic is not None and num_semantic:
        semantics = frame.semantic.reshape(-1, num_semantic)[idx]
        labels = frame.labels.reshape(-1)[idx]  # type: ignore[union-attr]
    else:
        semantics = torch.zeros(n, num_semantic, device=device, dtype=dtype)
        labels = torch.zeros(n, dtype=torch.long, device=device)
    log_scale = torch.log(radius.clamp_min(1e-6))[:, None]
    logit = math.log(settings.initial_opacity / (1 - settings.initial_opacity))
    return GaussianMap(
        means=points.to(dtype),
        log_scales=log_scale.expand(n, 3).contiguous() if anisotropic else log_scale,
        logit_opacities=torch.full((n,), logit, device=device, dtype=dtype),
        colors=colors,
        semantics=semantics,
        labels=labels,
        birth_frame=torch.full((n,), frame.index, dtype=torch.long, device=device),
        quats=torch.tensor([1.0, 0.0, 0.0, 0.0], device=device, dtype=dtype).expand(n, 4).contiguous()
        if anisotropic
        else None,
    )


def _cell_keys(points: Tensor, cell_m: float) -> Tensor:  # [M, 3] -> [M] int64
    """One integer per cubic cell of ``cell_m`` metres (21 bits per axis: +-1 km at 1 mm)."""
    ijk = torch.floor(points / cell_m).long() & 0x1FFFFF
    return (ijk[:, 0] << 42) | (ijk[:, 1] << 21) | ijk[:, 2]


def spaced(
    points: Tensor,  # [M, 3] candidate centres (m)
    radii: Tensor,  # [M] their radii (m): one pixel's footprint
    existing: GaussianMap | None,
    spacing: float,
) -> Tensor:  # [M] bool, True = add
    """Candidates whose cell holds no Gaussian of ``existing`` and no earlier candidate.

    A candidate's cell is ``spacing`` x its radius, rounded up to 1 mm x a power of two, so the
    map keeps about one Gaussian per ``spacing`` footprints wherever it already has one, at any depth.
    """
    level = torch.ceil(torch.log2((spacing * radii / _CELL_BASE_M).clamp_min(1.0))).long()
    keep = torch.zeros(points.shape[0], dtype=torch.bool, device=points.device)
    means = existing.means.detach() if existing is not None and len(existing) else None
    for lv in torch.unique(level).tolist():
        at = torch.nonzero(level == lv).squeeze(1)
        cell = _CELL_BASE_M * 2.0**lv
        keys = _cell_keys(points[at], cell)
        cells, inverse = torch.unique(keys, return_inverse=True)
        order = torch.arange(at.numel(), device=points.device)
        first = torch.full((cells.numel(),), at.numel(), dtype=torch.long, device=points.device)
        first = first.scatter_reduce(0, inverse, order, reduce="amin")
        free = first[inverse] == order  # the first candidate of each cell
        if means is not None:
            free &= ~torch.isin(keys, _cell_keys(means, cell))
        keep[at] = free
    return keep


def over_budget(
    gaussians: GaussianMap, incoming: int, max_gaussians: int, locked: frozenset[int] = frozenset()
) -> Tensor:  # [N] bool, True = remove
    """The least opaque Gaussians to drop so that the map plus ``incoming`` new ones holds ``max_gaussians``.

    Gaussians of ``locked`` classes (edits) are never dropped, so the cap yields to them.
    """
    remove = torch.zeros(len(gaussians), dtype=torch.bool, device=gaussians.device)
    excess = len(gaussians) + incoming - max_gaussians
    if excess <= 0:
        return remove
    opacity = gaussians.logit_opacities.detach()
    if locked:
        ids = torch.tensor(sorted(locked), dtype=torch.long, device=gaussians.device)
        opacity = torch.where(torch.isin(gaussians.labels, ids), torch.inf, opacity)
    excess = min(excess, int(torch.isfinite(opacity).sum()))
    remove[torch.topk(opacity, excess, largest=False).indices] = True
    return remove


def scene_radius(first_depth: np.ndarray, depth_ratio: float) -> float:
    """SplaTAM's scene radius: max first-frame depth / ratio (m); used to prune huge Gaussians."""
    valid = first_depth[first_depth > 0]
    return float(valid.max() / depth_ratio) if valid.size else 1.0


def densify_frame(
    gaussians: GaussianMap,
    data: FrameTensors,
    frame: Frame,  # the same frame on the host (a lower densification resolution resizes it)
    c2w: np.ndarray,  # [4, 4] its estimated pose
    *,
    rendered: RenderOutput | None = None,  # ``gaussians`` already rendered from ``c2w``
    revisit: bool = False,  # a keyframe saw this view long ago: a mapped edge adds nothing
    settings: DensifySettings,
    kernels: Kernels,
    codec: SemanticCodec,
    edits: EditLocks,
    generator: torch.Generator,
) -> tuple[GaussianMap, int]:  # the map with the new Gaussians, how many were added
    """Add Gaussians where ``gaussians`` do not explain the frame (all of it for an empty map), within the budget.

    Pixels at a mapped edge (``densify_mask``) add Gaussians unless the view is a ``revisit``: a new
    edge sharpens, and one seen from the same place before renders the same blend every time.
    """
    device = data.depth.device
    c2w_t = torch.as_tensor(c2w, dtype=torch.float32, device=device)
    if len(gaussians) == 0:
        mask = data.valid
    else:
        if rendered is None:
            with torch.no_grad():
                rendered = kernels.render(gaussians, data.intrinsics, se3_inverse(c2w_t), with_semantics=False)
        reasons = densify_mask(rendered, data, settings)
        mask = reasons.empty | reasons.in_front if revisit else reasons.union()
    source = data
    scale = settings.scale_for(frame.intrinsics.width)
    if scale < 1.0:
        rgb, depth, labels, k = resize_arrays(frame.rgb, frame.depth, frame.labels, frame.intrinsics, scale)
        source = FrameTensors.from_arrays(data.index, k, rgb, depth, labels, codec, device)
        source = source.with_ignore(edits.ignore_mask(source.labels))
        mask = torch.nn.functional.interpolate(mask[None, None].float(), size=k.shape, mode="nearest")[0, 0] > 0.5
        mask &= source.valid
    new = gaussians_from_pixels(
        source, c2w_t, mask, codec.num_channels, settings, generator=generator, existing=gaussians
    )
    if settings.max_gaussians is not None:  # the Gaussian budget: the least opaque make room
        gaussians = gaussians.prune(over_budget(gaussians, len(new), settings.max_gaussians, edits.locked_labels))
    return gaussians.cat(new), len(new)
