"""Classes for Gaussians mapped before any label reached them, from a view's late label image.

Live, a frame is mapped before its label image exists, so the Gaussians it adds start unlabelled.
When the labels come, each unlabelled Gaussian that the labelled view sees at its own depth takes
the class (and semantic target) of the pixel it projects to: what densification would have given
it had the labels been on time. Gaussians that already have a class keep it; the mapping steps on
labelled views refine their semantic features.
"""

from __future__ import annotations

import torch
from torch import Tensor

from sgs_slam_core.frame_data import FrameTensors
from sgs_slam_core.gaussians import GaussianMap

__all__ = ["label_unlabelled"]

# A centre counts as seen at its pixel when its depth is within this of the measured depth: a
# Kinect's depth noise grows to ~2 cm at 3 m, and a Gaussian sits up to a pixel's footprint off it.
_DEPTH_TOLERANCE_M = 0.02
_DEPTH_TOLERANCE_RELATIVE = 0.02


def label_unlabelled(
    gaussians: GaussianMap,
    view: FrameTensors,  # labels and semantic set
    w2c: Tensor,  # [4, 4] the view's world-to-camera pose
) -> tuple[GaussianMap, int]:
    """``gaussians`` with the unlabelled ones the view sees labelled from it; how many took a class."""
    if view.labels is None or view.semantic is None or not len(gaussians):
        return gaussians, 0
    k = view.intrinsics
    w2c = w2c.to(gaussians.means.dtype)
    cam = gaussians.means @ w2c[:3, :3].T + w2c[:3, 3]  # [N, 3]
    z = cam[:, 2]
    front = z > 1e-6
    safe_z = torch.where(front, z, torch.ones_like(z))
    u = torch.round(k.fx * cam[:, 0] / safe_z + k.cx).long()
    v = torch.round(k.fy * cam[:, 1] / safe_z + k.cy).long()
    candidate = front & (u >= 0) & (u < k.width) & (v >= 0) & (v < k.height) & (gaussians.labels == 0)
    idx = torch.nonzero(candidate).squeeze(1)  # [M]
    pixel = v[idx] * k.width + u[idx]  # [M]
    measured = torch.where(view.valid, view.depth, 0.0).reshape(-1)[pixel]
    labels = view.labels.reshape(-1)[pixel]
    close = (z[idx] - measured).abs() <= _DEPTH_TOLERANCE_M + _DEPTH_TOLERANCE_RELATIVE * measured
    take = (measured > 0) & close & (labels > 0)
    idx, pixel = idx[take], pixel[take]
    if not idx.numel():
        return gaussians, 0
    semantic = view.semantic.reshape(-1, view.semantic.shape[-1])[pixel].to(gaussians.semantics.dtype)
    new_labels = gaussians.labels.index_put((idx,), labels[take].to(gaussians.labels.dtype))
    new_semantics = gaussians.semantics.index_put((idx,), semantic)
    return gaussians.with_tensors(labels=new_labels, semantics=new_semantics), int(idx.numel())
