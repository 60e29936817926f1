"""Classes for Gaussians mapped before any label reached them, from a view's late label image.

Live, a frame is mapped before its label image exists, so the Gaussians it adds start unlabelled.
When the labels come, each unlabelled Gaussian that the labelled view sees at its own depth takes
the class (and semantic target) of the pixel it projects to: what densification would have given
it had the labels been on time. Gaussians that already have a class keep it; the mapping steps on
labelled views refine their semantic features.
"""

from __future__ import annotations

from torch import Tensor

from sgs_slam_core.frame_data import FrameTensors
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.slam.label_votes import seen_classes

__all__ = ["label_unlabelled"]


def label_unlabelled(
    gaussians: GaussianMap,
    view: FrameTensors,  # labels and semantic set
    w2c: Tensor,  # [4, 4] the view's world-to-camera pose
) -> tuple[GaussianMap, int]:
    """``gaussians`` with the unlabelled ones the view sees labelled from it; how many took a class."""
    if view.labels is None or view.semantic is None:
        return gaussians, 0
    rows, classes, pixel = seen_classes(gaussians, view, w2c)
    unlabelled = gaussians.labels[rows] == 0
    rows, classes, pixel = rows[unlabelled], classes[unlabelled], pixel[unlabelled]
    if not rows.numel():
        return gaussians, 0
    semantic = view.semantic.reshape(-1, view.semantic.shape[-1])[pixel].to(gaussians.semantics.dtype)
    new_labels = gaussians.labels.index_put((rows,), classes.to(gaussians.labels.dtype))
    new_semantics = gaussians.semantics.index_put((rows,), semantic)
    return gaussians.with_tensors(labels=new_labels, semantics=new_semantics), int(rows.numel())
