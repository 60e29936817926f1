"""Keyframe window selection: geometric overlap, the paper's semantic filter, U(t) weights."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from sgs_slam_core.config.sections import KeyframeSettings
from sgs_slam_core.frame import CompactFrame

__all__ = [
    "OVERLAP_BORDER_FRAC",
    "Window",
    "is_keyframe",
    "label_miou",
    "label_miou_per_class",
    "overlap_scores",
    "select_window",
]

# Projections within this fraction of the width from a keyframe's border do not count as overlap.
OVERLAP_BORDER_FRAC = 0.02


def is_keyframe(index: int, every: int, last: int | None = None) -> bool:
    """Frame 0 and every frame with (index + 1) % every == 0 (the reference's rule).

    ``last``: the latest keyframe's index. When frames are skipped (live mapping takes the newest
    tracked frame), the first frame past such a boundary since ``last`` counts; with every frame
    offered this is the same rule.
    """
    if index == 0 or last is None:
        return index == 0 or (index + 1) % every == 0
    return (index + 1) // every > (last + 1) // every


def overlap_scores(
    points_world: np.ndarray,  # [M, 3]
    keyframes: Sequence[CompactFrame],
    border_frac: float,
) -> np.ndarray:  # [K]
    """Fraction of the points that land inside each keyframe's image (minus a border), in front of it."""
    scores = np.zeros(len(keyframes))
    if points_world.shape[0] == 0:
        return scores
    homo = np.concatenate([points_world, np.ones((points_world.shape[0], 1))], axis=1)
    for i, kf in enumerate(keyframes):
        k = kf.intrinsics
        cam = homo @ kf.w2c.T
        z = cam[:, 2]
        safe = np.where(z > 1e-6, z, 1.0)
        u = k.fx * cam[:, 0] / safe + k.cx
        v = k.fy * cam[:, 1] / safe + k.cy
        b = border_frac * k.width
        inside = (z > 1e-6) & (u >= b) & (u <= k.width - 1 - b) & (v >= b) & (v <= k.height - 1 - b)
        scores[i] = inside.mean()
    return scores


_CONFUSION_CELLS = 1 << 20  # label ids below 1024: the confusion matrix fits in 8 MB


def label_miou(a: np.ndarray, b: np.ndarray) -> float:
    """Pixel-wise mIoU of two label images over the classes present in either (0 ignored).

    One pass over the images into a confusion matrix of the ids, where ``label_miou_per_class``
    makes three per class (it takes the ids that do not fit a matrix).
    """
    if a.shape != b.shape:
        raise ValueError(f"label images differ in size: {a.shape} vs {b.shape}")
    if a.size == 0:
        return 0.0
    lo = min(int(a.min()), int(b.min()))
    top = max(int(a.max()), int(b.max())) + 1
    if lo < 0 or top * top > _CONFUSION_CELLS:
        return label_miou_per_class(a, b)
    codes = a.ravel().astype(np.int64) * top + b.ravel()
    confusion = np.bincount(codes, minlength=top * top).reshape(top, top)  # [class in a, class in b]
    inter = np.diag(confusion)
    union = confusion.sum(axis=1) + confusion.sum(axis=0) - inter
    present = union > 0
    present[0] = False
    if not present.any():
        return 0.0
    return float(np.mean(inter[present] / union[present]))


def label_miou_per_class(a: np.ndarray, b: np.ndarray) -> float:
    """``label_miou`` with one pass per class: the reference, and the path for any ids."""
    if a.shape != b.shape:
        raise ValueError(f"label images differ in size: {a.shape} vs {b.shape}")
    classes = np.union1d(np.unique(a), np.unique(b))
    classes = classes[classes > 0]
    if classes.size == 0:
        return 0.0
    ious = [((a == c) & (b == c)).sum() / ((a == c) | (b == c)).sum() for c in classes]
    return float(np.mean(ious))


@dataclass(frozen=True)
class Window:
    """Keyframes chosen for one mapping step (indices into the store) and their loss weights."""

    keyframes: tuple[int, ...]  # store indices, the most recent keyframe included
    weights: tuple[float, ...]  # per keyframe, then the current frame last
    candidates: int  # keyframes with any overlap before the filters
    after_geometric: int
    after_semantic: int


def select_window(
    store: Sequence[CompactFrame],
    points_world: np.ndarray,  # [M, 3] sampled from the current frame at its estimated pose
    current_labels: np.ndarray | None,  # [H, W]
    current_index: int,
    s: KeyframeSettings,
    rng: np.random.Generator,
) -> Window:
    """Choose the mapping window's keyframes and loss weights.

    Up to ``window_size - 2`` past keyframes plus the most recent one (the current frame is always
    mapped too): overlap > 0 (or > eta with the geometric filter), then those whose label mIoU with
    the current frame exceeds T_sem are dropped, then a random subset is taken (as the reference).
    """
    if not store:
        return Window((), (1.0,), 0, 0, 0)
    older = store[:-1]
    scores = overlap_scores(points_world, older, OVERLAP_BORDER_FRAC)
    keep = [i for i, sc in enumerate(scores) if sc > 0]
    candidates = len(keep)
    if s.geometric_filter:
        keep = [i for i in keep if scores[i] > s.geometric_threshold]
    after_geo = len(keep)
    if s.semantic_filter and current_labels is not None:
        keep = [
            i
            for i in keep
            if older[i].labels is None
            or older[i].labels.shape != current_labels.shape
            or label_miou(older[i].labels, current_labels) <= s.semantic_threshold
        ]
    after_sem = len(keep)
    keep = [keep[j] for j in rng.permutation(len(keep))[: max(s.window_size - 2, 0)]]
    chosen = (*sorted(keep), len(store) - 1)
    frames = [store[i].index for i in chosen] + [current_index]
    if s.uncertainty_weighting:
        oldest = min(frames)
        weights = tuple(float(np.exp(-s.uncertainty_tau * (f - oldest))) for f in frames)
    else:
        weights = (1.0,) * len(frames)
    return Window(chosen, weights, candidates, after_geo, after_sem)
