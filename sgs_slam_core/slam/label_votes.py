"""Which class the labelled views say a Gaussian is: the pixels its centre falls on, and their consensus.

:func:`seen_classes` finds the Gaussians a labelled view sees (centre in the image, at the view's
measured depth) and the class of the pixel each lands on. :func:`cast_votes` folds one view's
classes into each Gaussian's ``labels`` / ``label_weight`` with the one-counter majority vote
(Misra-Gries, k = 1): agreement adds 1, disagreement takes 1 away, and at 0 the next class seen
takes over. A class that most views give a Gaussian is the one it ends with, whatever order they
come in, so a segmenter's flicker in a few views does not move it; the state is one float a
Gaussian, whatever the number of classes.
"""

from __future__ import annotations

import torch
from torch import Tensor

from sgs_slam_core.frame_data import FrameTensors
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.geometry.camera import Intrinsics

__all__ = ["cast_votes", "project_centres", "seen_classes"]

# A centre counts as seen at its pixel when its depth is within this of the measured depth: a
# Kinect's depth noise grows to ~2 cm at 3 m, and a Gaussian sits up to a pixel's footprint off it.
_DEPTH_TOLERANCE_M = 0.02
_DEPTH_TOLERANCE_RELATIVE = 0.02


def project_centres(
    means: Tensor,  # [N, 3] world points
    w2c: Tensor,  # [4, 4]
    k: Intrinsics,
) -> tuple[Tensor, Tensor, Tensor, Tensor]:  # [N, 3] camera frame, [N] int64 column, [N] int64 row, [N] bool
    """Points in the camera frame, the pixel each lands on (rounded), and whether it is in front and in the image."""
    w2c = w2c.to(means.dtype)
    cam = means @ w2c[:3, :3].T + w2c[:3, 3]
    z = cam[:, 2]
    front = z > 1e-6
    safe_z = torch.where(front, z, torch.ones_like(z))
    u = torch.round(k.fx * cam[:, 0] / safe_z + k.cx).long()
    v = torch.round(k.fy * cam[:, 1] / safe_z + k.cy).long()
    inside = front & (u >= 0) & (u < k.width) & (v >= 0) & (v < k.height)
    return cam, u, v, inside


def seen_classes(
    gaussians: GaussianMap,
    view: FrameTensors,  # labels set
    w2c: Tensor,  # [4, 4] the view's world-to-camera pose
) -> tuple[Tensor, Tensor, Tensor]:  # [M] int64 rows, [M] int64 classes (> 0), [M] int64 pixel indices
    """The Gaussians ``view`` sees at its measured depth on a labelled pixel, that pixel's class, and the pixel."""
    empty = torch.zeros(0, dtype=torch.long, device=gaussians.device)
    if view.labels is None or not len(gaussians):
        return empty, empty, empty
    k = view.intrinsics
    cam, u, v, inside = project_centres(gaussians.means, w2c, k)
    z = cam[:, 2]
    rows = torch.nonzero(inside).squeeze(1)  # [M]
    pixel = v[rows] * k.width + u[rows]  # [M]
    measured = torch.where(view.valid, view.depth, 0.0).reshape(-1)[pixel]
    classes = view.labels.reshape(-1)[pixel].long()
    close = (z[rows] - measured).abs() <= _DEPTH_TOLERANCE_M + _DEPTH_TOLERANCE_RELATIVE * measured
    take = (measured > 0) & close & (classes > 0)
    return rows[take], classes[take], pixel[take]


def cast_votes(
    gaussians: GaussianMap,
    rows: Tensor,  # [M] int64 distinct rows
    classes: Tensor,  # [M] int64 the class one view gives each
    locked: Tensor | None = None,  # [L] int64 class ids that neither gain nor lose Gaussians
) -> GaussianMap:
    """``gaussians`` with one view's classes voted into ``labels`` / ``label_weight`` (one vote a row)."""
    if locked is not None and locked.numel() and rows.numel():
        free = ~(torch.isin(gaussians.labels[rows], locked) | torch.isin(classes, locked))
        rows, classes = rows[free], classes[free]
    if not rows.numel():
        return gaussians
    current, weight = gaussians.labels[rows], gaussians.label_weight[rows]
    agree = current == classes
    take_over = ~agree & (weight <= 0)  # nothing left for the old class: the new one starts at 1
    new_weight = torch.where(agree | take_over, weight.abs() + 1, weight - 1)
    new_label = torch.where(take_over, classes, current)
    labels = gaussians.labels.index_put((rows,), new_label)
    label_weight = gaussians.label_weight.index_put((rows,), new_weight)
    return gaussians.with_tensors(labels=labels, label_weight=label_weight)
