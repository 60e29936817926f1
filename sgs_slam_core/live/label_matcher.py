"""Label images that come late, matched by stamp to the views already mapped.

A segmenter is slower than the camera and behind it, so live its label images arrive after their
colour image was tracked and mapped. The matcher keeps the last seconds of mapped views (pose,
colour and depth at the processing size, compact) and pairs each label image with the view of its
stamp; a label image that arrives before its view is held as long as a view is kept. Every label
image is accounted for: fused (matched), unmatched (its view was never mapped, or left the buffer),
or still pending. Not thread-safe: the live pipeline calls it under its lock.
"""

from __future__ import annotations

from collections import OrderedDict, deque
from dataclasses import dataclass

import numpy as np

from sgs_slam_core.frame import CompactFrame

__all__ = ["LabelCounts", "LabelMatcher", "LateLabels"]


@dataclass(frozen=True)
class LateLabels:
    """A label image and the mapped view of its stamp, ready to fuse."""

    view: CompactFrame  # labels None: the view as mapped
    labels: np.ndarray  # [H, W] integer class ids at the view's size, 0 = unlabelled
    arrived_at: float  # s, monotonic: when the label image arrived
    view_arrived_at: float  # s, monotonic: when the view's frame arrived


@dataclass
class LabelCounts:
    """What became of the label images handed over (for /diagnostics and metrics.json)."""

    labels_in: int = 0
    labels_matched: int = 0  # paired with a mapped view (fused, or waiting to be)
    labels_unmatched: int = 0  # no mapped view of their stamp within the buffer's time
    labels_fused: int = 0  # fused into the map


class LabelMatcher:
    """Recent mapped views and label images waiting for theirs, both kept for ``keep_s`` seconds of stamps.

    ``tolerance_ns``: how far a label image's stamp may lie from its view's (a segmenter copies
    the colour image's stamp, so a small tolerance only absorbs rounding).
    """

    def __init__(self, keep_s: float, tolerance_ns: int = 1_000_000) -> None:
        self.keep_ns = round(keep_s * 1e9)
        self.tolerance_ns = tolerance_ns
        self.counts = LabelCounts()
        self._views: OrderedDict[int, tuple[CompactFrame, float]] = OrderedDict()  # stamp_ns -> (view, arrival s)
        self._pending: deque[tuple[int, np.ndarray, float]] = deque()  # (stamp_ns, labels, arrived_at)
        self._newest_ns: int | None = None

    @property
    def enabled(self) -> bool:
        """False when nothing is kept (``keep_s`` 0): label images are then all unmatched."""
        return self.keep_ns > 0

    @property
    def pending(self) -> int:
        """Label images waiting for their view."""
        return len(self._pending)

    @property
    def nbytes(self) -> int:
        """Host memory held by the kept views and pending label images."""
        return sum(v.nbytes for v, _ in self._views.values()) + sum(p[1].nbytes for p in self._pending)

    def add_view(self, view: CompactFrame, arrived_at: float = 0.0) -> list[LateLabels]:
        """Keep a mapped view (its frame arrived at ``arrived_at``, s); returns the pending label images it matches."""
        if not self.enabled:
            return []
        self._views[view.stamp_ns] = (view, arrived_at)
        self._newest_ns = view.stamp_ns if self._newest_ns is None else max(self._newest_ns, view.stamp_ns)
        matched, waiting = [], deque()
        for item in self._pending:
            stamp_ns, labels, labels_arrived_at = item
            if abs(stamp_ns - view.stamp_ns) <= self.tolerance_ns:
                matched.append(LateLabels(view, labels, labels_arrived_at, arrived_at))
            else:
                waiting.append(item)
        self._pending = waiting
        self.counts.labels_matched += len(matched)
        self._expire()
        return matched

    def add_labels(self, stamp_ns: int, labels: np.ndarray, arrived_at: float) -> LateLabels | None:
        """A label image of ``stamp_ns``: its view when one is kept; else held (or counted unmatched)."""
        self.counts.labels_in += 1
        found = self._find(stamp_ns)
        if found is not None:
            self.counts.labels_matched += 1
            return LateLabels(found[0], labels, arrived_at, found[1])
        if not self.enabled or (self._newest_ns is not None and stamp_ns < self._newest_ns - self.keep_ns):
            self.counts.labels_unmatched += 1  # its view left the buffer long ago (or none is kept)
            return None
        self._pending.append((stamp_ns, labels, arrived_at))
        self._expire()
        return None

    def clear(self) -> None:
        """Forget views and pending labels (a reset); pending ones count as unmatched."""
        self.counts.labels_unmatched += len(self._pending)
        self._views.clear()
        self._pending.clear()
        self._newest_ns = None

    def _find(self, stamp_ns: int) -> tuple[CompactFrame, float] | None:
        if not self._views:
            return None
        stamps = np.fromiter(self._views.keys(), dtype=np.int64, count=len(self._views))
        nearest = int(stamps[np.argmin(np.abs(stamps - stamp_ns))])
        return self._views[nearest] if abs(nearest - stamp_ns) <= self.tolerance_ns else None

    def _expire(self) -> None:
        """Drop views and pending labels older than ``keep_s`` before the newest view (pending: counted)."""
        if self._newest_ns is None:
            return
        oldest = self._newest_ns - self.keep_ns
        while self._views and next(iter(self._views)) < oldest:
            self._views.popitem(last=False)
        while self._pending and self._pending[0][0] < oldest:
            self._pending.popleft()
            self.counts.labels_unmatched += 1
