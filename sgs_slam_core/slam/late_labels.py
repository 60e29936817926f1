"""Classes for Gaussians mapped before any label reached them, from a view's late label image.

Live, a frame is mapped before its label image exists, so the Gaussians it adds start unlabelled.
When the labels come, each unlabelled Gaussian that the labelled view sees at its own depth takes
the class (and semantic target) of the pixel it projects to: what densification would have given
it had the labels been on time. An unlabelled Gaussian the view does not see at its depth (beside
the measured surface, at a depth edge) takes the class of the nearest labelled surface point the
view measured within a few pixel footprints of it: left unlabelled, its zero features would
darken every rendered class colour it overlaps, and a darkened colour decodes to another class.
Gaussians that already have a class keep it; the mapping steps on labelled views refine their
semantic features.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from sgs_slam_core.frame_data import FrameTensors
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.geometry.camera import vertex_map
from sgs_slam_core.slam.label_votes import project_centres, seen_classes

__all__ = ["NEIGHBOUR_FOOTPRINTS", "label_unlabelled"]

# An unlabelled Gaussian takes the class of a measured point within this many pixel footprints
# (depth / focal length) of it: densification spaces Gaussians about one footprint apart, so a few
# reach the surface it was added beside, and not a surface across a depth edge.
NEIGHBOUR_FOOTPRINTS = 3.0


def label_unlabelled(
    gaussians: GaussianMap,
    view: FrameTensors,  # labels and semantic set
    w2c: Tensor,  # [4, 4] the view's world-to-camera pose
    seen: tuple[Tensor, Tensor, Tensor] | None = None,  # seen_classes(gaussians, view, w2c) when already made
) -> tuple[GaussianMap, int]:
    """``gaussians`` with the unlabelled ones the view sees labelled from it; how many took a class."""
    if view.labels is None or view.semantic is None:
        return gaussians, 0
    rows, classes, pixel = seen if seen is not None else seen_classes(gaussians, view, w2c)
    unlabelled = gaussians.labels[rows] == 0
    at_depth, at_depth_pixel = rows[unlabelled], pixel[unlabelled]
    near, near_pixel = _beside_surface(gaussians, view, w2c, exclude=rows)
    taken, taken_pixel = torch.cat([at_depth, near]), torch.cat([at_depth_pixel, near_pixel])
    if not taken.numel():
        return gaussians, 0
    classes = view.labels.reshape(-1)[taken_pixel].to(gaussians.labels.dtype)
    target = view.semantic.reshape(-1, view.semantic.shape[-1])[taken_pixel].to(gaussians.semantics.dtype)
    labels = gaussians.labels.index_put((taken,), classes)
    semantics = gaussians.semantics.index_put((taken,), target)
    return gaussians.with_tensors(labels=labels, semantics=semantics), int(taken.numel())


def _beside_surface(
    gaussians: GaussianMap,
    view: FrameTensors,
    w2c: Tensor,  # [4, 4]
    exclude: Tensor,  # [M] int64 rows the view sees at their depth (labelled from their own pixel)
) -> tuple[Tensor, Tensor]:  # [U] int64 rows, [U] int64 the pixel each takes its class from
    """Unlabelled Gaussians in the view with a labelled measured point within reach, and that point's pixel.

    The search looks at the pixels around a Gaussian's projection that can hold a point within
    reach (``NEIGHBOUR_FOOTPRINTS`` footprints project to as many pixels), so it costs a
    window's pixels a Gaussian, whatever the size of the map.
    """
    k = view.intrinsics
    empty = torch.zeros(0, dtype=torch.long, device=gaussians.device)
    unlabelled = gaussians.labels == 0
    unlabelled[exclude] = False
    rows = torch.nonzero(unlabelled).squeeze(1)  # [U0]
    if not rows.numel():
        return empty, empty
    cam, u, v, inside = project_centres(gaussians.means[rows], w2c, k)  # [U0, 3], [U0] x 3
    rows, cam, u, v = rows[inside], cam[inside], u[inside], v[inside]
    if not rows.numel():
        return empty, empty
    r = math.ceil(NEIGHBOUR_FOOTPRINTS)
    offsets = torch.arange(-r, r + 1, device=rows.device)
    du, dv = offsets.repeat(2 * r + 1), offsets.repeat_interleave(2 * r + 1)  # [W] the window's pixels
    pu, pv = u[:, None] + du, v[:, None] + dv  # [U, W]
    within = (pu >= 0) & (pu < k.width) & (pv >= 0) & (pv < k.height)
    pixel = pv.clamp(0, k.height - 1) * k.width + pu.clamp(0, k.width - 1)  # [U, W]
    depth = torch.where(view.valid, view.depth, torch.zeros_like(view.depth))
    points = vertex_map(depth, k).reshape(-1, 3)  # [H * W, 3] camera frame
    usable = within & (depth.reshape(-1)[pixel] > 0) & (view.labels.reshape(-1)[pixel] > 0)
    distance = torch.linalg.vector_norm(points[pixel] - cam[:, None, :], dim=-1)  # [U, W]
    distance = torch.where(usable, distance, torch.full_like(distance, math.inf))
    best = distance.min(dim=1)
    reach = NEIGHBOUR_FOOTPRINTS * cam[:, 2] * (2.0 / (k.fx + k.fy))  # [U] m
    close = best.values <= reach
    return rows[close], pixel[close, best.indices[close]]
