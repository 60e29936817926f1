"""Semantic segmentation metrics on class-id images.

* :class:`ConfusionMatrix` - the standard: one confusion matrix accumulated over every evaluated
  frame; mIoU over the classes present in the ground truth; pixels labelled 0 (unlabelled) in the
  ground truth are ignored.
* :func:`paper_frame_miou` - SGS-SLAM's protocol for one frame (predictions decoded with the ids
  present in that frame's ground truth as the only candidates; IoU averaged over those ids, 0
  excluded); the paper's score is the mean over frames. Classes absent from a frame can never be
  predicted there, which makes it higher than the standard mIoU.
"""

from __future__ import annotations

import numpy as np

from sgs_slam_core.errors import ShapeError

__all__ = ["ConfusionMatrix", "paper_frame_miou"]


def _as_ids(a: object, name: str) -> np.ndarray:
    arr = np.asarray(a.detach().cpu() if hasattr(a, "detach") else a)  # type: ignore[union-attr]
    if not np.issubdtype(arr.dtype, np.integer):
        raise ShapeError(f"{name} must hold integer class ids, got {arr.dtype}")
    if arr.size and arr.min() < 0:
        raise ShapeError(f"{name} contains negative class ids")
    return arr.astype(np.int64).reshape(-1)


class ConfusionMatrix:
    """Rows: ground truth id; columns: predicted id. Grows to the largest id seen."""

    def __init__(self) -> None:
        self.matrix = np.zeros((1, 1), dtype=np.int64)

    def update(self, pred: object, gt: object) -> None:
        """Add one frame (``pred`` and ``gt`` are equally shaped id images)."""
        p, g = _as_ids(pred, "prediction"), _as_ids(gt, "ground truth")
        if p.shape != g.shape:
            raise ShapeError(f"prediction has {p.size} pixels, ground truth {g.size}")
        keep = g > 0
        p, g = p[keep], g[keep]
        if g.size == 0:
            return
        size = max(self.matrix.shape[0], int(p.max()) + 1, int(g.max()) + 1)
        if size > self.matrix.shape[0]:
            grown = np.zeros((size, size), dtype=np.int64)
            grown[: self.matrix.shape[0], : self.matrix.shape[1]] = self.matrix
            self.matrix = grown
        self.matrix += np.bincount(g * size + p, minlength=size * size).reshape(size, size)

    def iou(self) -> dict[int, float]:
        """IoU of every class present in the ground truth (id 0 excluded)."""
        m = self.matrix
        tp = np.diag(m)
        gt_count, pred_count = m.sum(1), m.sum(0)
        return {
            c: float(tp[c] / (gt_count[c] + pred_count[c] - tp[c])) for c in range(1, m.shape[0]) if gt_count[c] > 0
        }

    def miou(self) -> float:
        """Mean IoU over the classes present in the ground truth (nan when there are none)."""
        ious = self.iou()
        return float(np.mean(list(ious.values()))) if ious else float("nan")

    def pixel_accuracy(self) -> float:
        """Fraction of labelled pixels predicted correctly."""
        total = self.matrix.sum()
        return float(np.trace(self.matrix) / total) if total else float("nan")


def paper_frame_miou(pred: object, gt: object) -> float:
    """One frame of SGS-SLAM's mIoU: mean IoU over the non-zero ids present in ``gt``.

    ``pred`` must be decoded with the ids present in ``gt`` as candidates (colour mode: snap to the
    frame's ground-truth colours). Pixels labelled 0 in ``gt`` are discarded.
    """
    p, g = _as_ids(pred, "prediction"), _as_ids(gt, "ground truth")
    if p.shape != g.shape:
        raise ShapeError(f"prediction has {p.size} pixels, ground truth {g.size}")
    keep = g > 0
    p, g = p[keep], g[keep]
    ious = []
    for c in np.unique(g):
        pc, gc = p == c, g == c
        ious.append((pc & gc).sum() / (pc | gc).sum())
    return float(np.mean(ious)) if ious else float("nan")
