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
    """Rows: ground-truth class; columns: predicted class; over the class ids seen so far.

    The table is indexed by the sorted ids that occurred (``classes``), not by the ids themselves,
    so a label image holding id 65535 costs one row, not a 65536 x 65536 table.
    """

    def __init__(self) -> None:
        self.classes = np.zeros(0, dtype=np.int64)  # [K] sorted ids occurring in ground truth or prediction
        self.matrix = np.zeros((0, 0), dtype=np.int64)  # [K, K] pixel counts

    def update(self, pred: object, gt: object) -> None:
        """Add one frame (``pred`` and ``gt`` are equally shaped id images)."""
        p, g = _as_ids(pred, "prediction"), _as_ids(gt, "ground truth")
        if p.shape != g.shape:
            raise ShapeError(f"prediction has {p.size} pixels, ground truth {g.size}")
        keep = g > 0
        p, g = p[keep], g[keep]
        if g.size == 0:
            return
        frame_ids, codes = np.unique(np.concatenate([g, p]), return_inverse=True)
        merged = np.union1d(self.classes, frame_ids)
        if len(merged) > len(self.classes):  # re-index the table onto the grown id list
            grown = np.zeros((len(merged), len(merged)), dtype=np.int64)
            old = np.searchsorted(merged, self.classes)
            grown[np.ix_(old, old)] = self.matrix
            self.classes, self.matrix = merged, grown
        k = len(frame_ids)
        counts = np.bincount(codes[: g.size] * k + codes[g.size :], minlength=k * k).reshape(k, k)
        where = np.searchsorted(self.classes, frame_ids)
        self.matrix[np.ix_(where, where)] += counts

    @property
    def total(self) -> int:
        """Labelled pixels counted so far."""
        return int(self.matrix.sum())

    def iou(self) -> dict[int, float]:
        """IoU of every class present in the ground truth (id 0 excluded)."""
        m = self.matrix
        tp = np.diag(m)
        gt_count, pred_count = m.sum(1), m.sum(0)
        return {
            int(c): float(tp[i] / (gt_count[i] + pred_count[i] - tp[i]))
            for i, c in enumerate(self.classes)
            if c > 0 and gt_count[i] > 0
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
    if g.size == 0:
        return float("nan")
    ids, codes = np.unique(np.concatenate([g, p]), return_inverse=True)  # compact: no table per id value
    gc, pc = codes[: g.size], codes[g.size :]
    inter = np.bincount(gc[gc == pc], minlength=len(ids))
    gt_count, pred_count = np.bincount(gc, minlength=len(ids)), np.bincount(pc, minlength=len(ids))
    present = gt_count > 0
    return float(np.mean(inter[present] / (gt_count[present] + pred_count[present] - inter[present])))
