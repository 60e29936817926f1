"""A segmenter's mistakes, made from true labels: the label noise of benchmarks and tests.

A network's label images differ from the truth the same few ways: a whole object region takes
another class for a frame and is right again in the next (flicker), some classes are mistaken for
one particular other class (confusion: wall for ceiling, chair for sofa), class boundaries bleed a
few pixels into the neighbour, and some frames get no label image at all (the segmenter was busy).
:class:`NoisyLabels` feeds a labelled dataset's frames with their labels degraded so, frame by
frame from a seed, and keeps the true labels for the evaluation. ``sgs-slam run --label-noise``
uses it; :data:`LABEL_NOISE_LEVELS` names the levels.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, replace

import cv2
import numpy as np

from sgs_slam_core.datasets.base import Dataset
from sgs_slam_core.errors import ConfigError
from sgs_slam_core.frame import Frame
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.labels import LabelTable

__all__ = ["LABEL_NOISE_LEVELS", "LabelNoise", "NoisyLabels", "confusion_partners", "degrade_labels"]


@dataclass(frozen=True)
class LabelNoise:
    """How label images differ from the truth.

    Attributes:
        unlabelled: fraction of frames that get no label image.
        flicker: chance, per frame and object region (a connected region of one class), that the
            region takes another class present in the frame.
        confusion: chance, per frame and region, that the region takes its class's fixed
            confusion partner (:func:`confusion_partners`).
        bleed_px: class boundaries move by this many pixels (at the frames' size), one class of each
            boundary growing over the other; which one is drawn per frame.
    """

    unlabelled: float = 0.0
    flicker: float = 0.0
    confusion: float = 0.0
    bleed_px: int = 0

    def __post_init__(self) -> None:
        for name in ("unlabelled", "flicker", "confusion"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ConfigError(f"label noise {name} must be in [0, 1], got {value}")
        if not 0 <= self.bleed_px <= 64:
            raise ConfigError(f"label noise bleed_px must be in [0, 64], got {self.bleed_px}")


# On the synthetic room at 160x120 the levels' label images score about 71, 64 and 47 % mIoU against
# the truth (BENCHMARKS.md); the middle one is about what an indoor network gives on data it was not
# trained on. A region's flip costs far more mIoU than a pixel's, so the chances are small.
LABEL_NOISE_LEVELS: dict[str, LabelNoise] = {
    "low": LabelNoise(unlabelled=0.05, flicker=0.02, confusion=0.02, bleed_px=1),
    "middle": LabelNoise(unlabelled=0.1, flicker=0.05, confusion=0.05, bleed_px=1),
    "high": LabelNoise(unlabelled=0.2, flicker=0.1, confusion=0.1, bleed_px=2),
}


def confusion_partners(ids: list[int], seed: int) -> dict[int, int]:
    """Each class id (> 0) mapped to another id of ``ids``, fixed by ``seed``: the class it is mistaken for."""
    classes = sorted({i for i in ids if i > 0})
    if len(classes) < 2:
        return {}
    rng = np.random.default_rng([seed, 0x5EC])
    partners = {}
    for c in classes:
        others = [o for o in classes if o != c]
        partners[c] = int(others[rng.integers(len(others))])
    return partners


def degrade_labels(
    labels: np.ndarray,  # [H, W] integer class ids, 0 = unlabelled
    noise: LabelNoise,
    partners: dict[int, int],
    rng: np.random.Generator,
) -> np.ndarray:  # [H, W] same dtype
    """``labels`` with regions flickered or confused and boundaries bled (unlabelled frames are the caller's)."""
    out = labels.copy()
    present = np.unique(labels[labels > 0])
    if noise.flicker > 0 or noise.confusion > 0:
        for c in present.tolist():
            count, regions = cv2.connectedComponents((labels == c).astype(np.uint8), connectivity=4)
            for r in range(1, count):
                draw = rng.random()
                if draw < noise.flicker and present.size > 1:
                    others = present[present != c]
                    out[regions == r] = others[rng.integers(others.size)]
                elif draw < noise.flicker + noise.confusion and c in partners:
                    out[regions == r] = partners[c]
    if noise.bleed_px > 0:
        out = _bleed(out, noise.bleed_px, rng)
    return out


def _bleed(labels: np.ndarray, px: int, rng: np.random.Generator) -> np.ndarray:
    """Each boundary moved ``px`` pixels: the class of higher random rank grows (unlabelled never does)."""
    ids = np.unique(labels)
    ranks = np.zeros(ids.size, dtype=np.int64)
    labelled = ids > 0
    ranks[labelled] = 1 + rng.permutation(int(labelled.sum()))  # rank 0 stays with id 0
    ranked = ranks[np.searchsorted(ids, labels)].astype(np.float32)  # float: OpenCV dilates up to 2^24 ranks exactly
    grown = cv2.dilate(ranked, np.ones((2 * px + 1, 2 * px + 1), np.uint8))
    by_rank = np.zeros(int(ranks.max()) + 1, dtype=labels.dtype)
    by_rank[ranks] = ids
    return by_rank[grown.astype(np.int64)]


class NoisyLabels:
    """A labelled dataset whose frames carry their labels degraded by ``noise`` (the truth stays in ``truth``).

    Each frame's noise is drawn from ``(seed, frame index)``: reading a frame twice, or in another
    order, gives the same label image.
    """

    def __init__(self, truth: Dataset, noise: LabelNoise, seed: int = 0) -> None:
        self.truth, self.noise, self.seed = truth, noise, seed
        self.name = truth.name
        self.partners = confusion_partners(truth.label_table.ids, seed)

    @property
    def intrinsics(self) -> Intrinsics:
        """The wrapped dataset's intrinsics."""
        return self.truth.intrinsics

    @property
    def label_table(self) -> LabelTable:
        """The wrapped dataset's class table."""
        return self.truth.label_table

    @property
    def has_ground_truth(self) -> bool:
        """Whether the wrapped dataset has ground-truth poses."""
        return self.truth.has_ground_truth

    @property
    def has_labels(self) -> bool:
        """Whether the wrapped dataset has labels."""
        return self.truth.has_labels

    @property
    def stamps_ns(self) -> list[int]:
        """The wrapped dataset's stamps (ns)."""
        return self.truth.stamps_ns

    def ground_truth(self, index: int) -> np.ndarray | None:
        """The wrapped dataset's ground-truth c2w [4, 4] of frame ``index``."""
        return self.truth.ground_truth(index)

    def __len__(self) -> int:
        return len(self.truth)

    def __iter__(self) -> Iterator[Frame]:
        return (self[i] for i in range(len(self)))

    def __getitem__(self, index: int) -> Frame:
        frame = self.truth[index]
        if frame.labels is None:
            return frame
        rng = np.random.default_rng([self.seed, index % len(self)])
        if rng.random() < self.noise.unlabelled:
            return replace(frame, labels=None)
        return replace(frame, labels=degrade_labels(frame.labels, self.noise, self.partners, rng))
