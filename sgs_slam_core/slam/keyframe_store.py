"""The keyframe store: compact host copies under a cap; when full, the best-covered view leaves.

Every kept keyframe carries a small sample of its back-projected pixels (world points) and a
thumbnail of its labels. When a keyframe arrives, each older one's points are projected into it
(the window selection's geometric overlap) and their thumbnails compared (the semantic mIoU of the
paper's filter). A keyframe that re-takes an older keyframe's view (camera near it, long after)
takes its place at once; when the store is still over its cap, the keyframe whose view a newer
keyframe covers best leaves. Revisiting a place replaces its old views instead of piling up new
ones, while views nothing newer sees (the only look at a corner) stay.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import overload

import numpy as np

from sgs_slam_core.config.sections import KeyframeSettings
from sgs_slam_core.frame import DEPTH_UNITS_PER_M, CompactFrame, compact_labels
from sgs_slam_core.geometry.views import views_near
from sgs_slam_core.slam.keyframes import OVERLAP_BORDER_FRAC, label_miou, overlap_scores

__all__ = ["KeyframeStore", "StoreStats", "view_points"]

_POINTS = 256  # world points per keyframe for the coverage test
_THUMB = 40  # label thumbnails are about this many pixels wide


@dataclass(frozen=True)
class StoreStats:
    """What the store holds now and what it has let go."""

    held: int  # keyframes with images
    nbytes: int  # host bytes of their images
    added: int  # keyframes ever added
    evicted: int  # keyframes dropped: re-taken views and those the caps pushed out


@dataclass
class _Entry:
    frame: CompactFrame
    points: np.ndarray  # [P, 3] world points sampled from the keyframe's depth
    thumb: np.ndarray | None  # [h, w] labels, subsampled
    covered: dict[int, float]  # newer keyframe index -> how well it covers this view, in [0, 1]


def view_points(kf: CompactFrame, count: int = _POINTS) -> np.ndarray:  # [P, 3]
    """Up to ``count`` pixels with depth, evenly spread over the image, back-projected to the world."""
    v, u = np.nonzero(kf.depth)
    if v.size == 0:
        return np.zeros((0, 3))
    pick = np.linspace(0, v.size - 1, min(count, v.size)).astype(np.int64)  # deterministic: no rng is drawn
    v, u = v[pick], u[pick]
    z = kf.depth[v, u].astype(np.float64) / DEPTH_UNITS_PER_M  # [P] m
    k = kf.intrinsics
    cam = np.stack([(u - k.cx) / k.fx * z, (v - k.cy) / k.fy * z, z], axis=1)
    c2w = np.linalg.inv(kf.w2c)
    return cam @ c2w[:3, :3].T + c2w[:3, 3]


def _thumbnail(labels: np.ndarray | None) -> np.ndarray | None:
    if labels is None:
        return None
    step = max(1, labels.shape[1] // _THUMB)
    return labels[::step, ::step]


class _Views:
    """Frame index, camera centre and optical axis of every keyframe, in arrays that grow by doubling."""

    def __init__(self) -> None:
        self._index = np.zeros(16, np.int64)
        self._centre = np.zeros((16, 3))
        self._axis = np.zeros((16, 3))
        self._n = 0

    def add(self, index: int, w2c: np.ndarray) -> None:
        if self._n == len(self._index):
            self._index = np.resize(self._index, 2 * self._n)
            self._centre = np.resize(self._centre, (2 * self._n, 3))
            self._axis = np.resize(self._axis, (2 * self._n, 3))
        rot = w2c[:3, :3]
        self._index[self._n] = index
        self._centre[self._n] = -rot.T @ w2c[:3, 3]
        self._axis[self._n] = rot[2]  # the camera's z axis in the world
        self._n += 1

    def near(self, c2w: np.ndarray, up_to_index: int, radius_m: float, angle_deg: float) -> bool:
        """Whether a view with frame index <= ``up_to_index`` lies within ``radius_m`` and ``angle_deg`` of ``c2w``."""
        return bool(self.near_indices(c2w, up_to_index, radius_m, angle_deg).size)

    def near_indices(self, c2w: np.ndarray, up_to_index: int, radius_m: float, angle_deg: float) -> np.ndarray:
        """Frame indices [K] of the views ``near`` counts."""
        n = self._n
        near = views_near(self._centre[:n], self._axis[:n], c2w, radius_m, angle_deg)
        return self._index[:n][(self._index[:n] <= up_to_index) & near]


class KeyframeStore(Sequence[CompactFrame]):
    """Keyframes in insertion order (oldest first) under ``max_keyframes`` and ``max_megabytes``.

    Indexing and iteration give the :class:`CompactFrame` s held, so window selection reads it as a
    list. The poses of every keyframe ever added stay (a map file lists them; 128 bytes each).
    """

    def __init__(self, settings: KeyframeSettings, frames: Sequence[CompactFrame] = ()) -> None:
        self.settings = settings
        self._entries: list[_Entry] = []
        self._poses: list[tuple[int, np.ndarray]] = []  # (frame index, w2c [4, 4]) of every keyframe added
        self._views = _Views()  # camera centres and optical axes of the same keyframes, for revisits
        self._nbytes = 0
        self.evicted = 0
        for kf in frames:
            self.add(kf)

    # ------------------------------------------------------------------ the sequence
    def __len__(self) -> int:
        return len(self._entries)

    @overload
    def __getitem__(self, i: int) -> CompactFrame: ...
    @overload
    def __getitem__(self, i: slice) -> list[CompactFrame]: ...
    def __getitem__(self, i: int | slice) -> CompactFrame | list[CompactFrame]:
        if isinstance(i, slice):
            return [e.frame for e in self._entries[i]]
        return self._entries[i].frame

    def __iter__(self) -> Iterator[CompactFrame]:
        return (e.frame for e in self._entries)

    def find(self, index: int) -> CompactFrame | None:
        """The held keyframe taken at frame ``index``, or None (never one, or let go)."""
        return next((e.frame for e in self._entries if e.frame.index == index), None)

    def attach_labels(self, index: int, labels: np.ndarray) -> bool:
        """Give the held keyframe of frame ``index`` its late label image [H, W]; False if none is held."""
        entry = next((e for e in self._entries if e.frame.index == index), None)
        if entry is None:
            return False
        self._nbytes -= entry.frame.nbytes
        entry.frame = dataclasses.replace(entry.frame, labels=compact_labels(labels))
        entry.thumb = _thumbnail(entry.frame.labels)
        self._nbytes += entry.frame.nbytes
        return True

    def labelled_near(self, index: int, frames: int) -> bool:
        """Whether a held keyframe with labels was taken fewer than ``frames`` frames from frame ``index``."""
        return any(e.frame.labels is not None and abs(e.frame.index - index) < frames for e in self._entries)

    # ------------------------------------------------------------------ state
    @property
    def nbytes(self) -> int:
        """Host bytes held by the keyframes' images."""
        return self._nbytes

    def stats(self) -> StoreStats:
        """Held, bytes, added and evicted counts."""
        return StoreStats(len(self._entries), self._nbytes, len(self._poses), self.evicted)

    def poses(self) -> list[tuple[int, np.ndarray]]:
        """(frame index, c2w [4, 4]) of every keyframe added, evicted ones included, oldest first."""
        return [(i, np.linalg.inv(w2c)) for i, w2c in self._poses]

    def revisited(self, c2w: np.ndarray, index: int, radius_m: float, angle_deg: float, min_age: int) -> bool:
        """Whether a keyframe at least ``min_age`` frames before ``index`` was taken near the view ``c2w`` [4, 4].

        Near: its camera centre within ``radius_m`` and its optical axis within ``angle_deg``.
        """
        return self._views.near(c2w, index - min_age, radius_m, angle_deg)

    # ------------------------------------------------------------------ adding and evicting
    def add(self, kf: CompactFrame) -> list[int]:
        """Keep ``kf`` (the newest keyframe); returns the frame indices of the keyframes it pushed out."""
        entry = _Entry(kf, view_points(kf), _thumbnail(kf.labels), {})
        self._score_against(entry)
        self._entries.append(entry)
        self._poses.append((kf.index, kf.w2c.copy()))
        self._views.add(kf.index, kf.w2c)
        self._nbytes += kf.nbytes
        retaken = self._retaken(entry)
        gone = [] if retaken is None else [self._remove(retaken)]
        while self._over_cap():
            victim = self._victim()
            if victim is None:
                break
            gone.append(self._remove(victim))
        return gone

    def _score_against(self, new: _Entry) -> None:
        """Record how well ``new`` covers each older keyframe's view (overlap, times label agreement)."""
        for e in self._entries:
            overlap = float(overlap_scores(e.points, [new.frame], OVERLAP_BORDER_FRAC)[0])
            if overlap > 0 and e.thumb is not None and new.thumb is not None and e.thumb.shape == new.thumb.shape:
                overlap *= 0.5 + 0.5 * label_miou(e.thumb, new.thumb)  # same view, same classes: redundant
            if overlap > 0:
                e.covered[new.frame.index] = overlap

    def _over_cap(self) -> bool:
        s = self.settings
        too_many = s.max_keyframes is not None and len(self._entries) > s.max_keyframes
        too_big = s.max_megabytes is not None and self._nbytes > s.max_megabytes * 2**20
        return too_many or too_big

    def _retaken(self, new: _Entry) -> int | None:
        """Position of the held keyframe whose view ``new`` re-takes (the one it covers best), or None.

        Re-taken: taken at least ``replace_min_age`` frames before ``new`` within ``replace_radius_m``
        and ``replace_angle_deg`` of it, seen by ``new``, and not among the newest ``keep_recent``.
        """
        s = self.settings
        if s.replace_radius_m is None:
            return None
        c2w = np.linalg.inv(new.frame.w2c)
        near = set(
            self._views.near_indices(
                c2w, new.frame.index - s.replace_min_age, s.replace_radius_m, s.replace_angle_deg
            ).tolist()
        )
        evictable = self._entries[: len(self._entries) - s.keep_recent]
        scores = [e.covered.get(new.frame.index, 0.0) if e.frame.index in near else 0.0 for e in evictable]
        if not scores or max(scores) <= 0:
            return None
        return int(np.argmax(scores))

    def _victim(self) -> int | None:
        """Position of the keyframe a newer one covers best (the oldest on ties); the newest are kept."""
        evictable = len(self._entries) - self.settings.keep_recent
        if evictable <= 0:
            return None
        scores = [max(e.covered.values(), default=0.0) for e in self._entries[:evictable]]
        return int(np.argmax(scores))

    def _remove(self, position: int) -> int:
        entry = self._entries.pop(position)
        self._nbytes -= entry.frame.nbytes
        self.evicted += 1
        for e in self._entries:
            e.covered.pop(entry.frame.index, None)  # a view that has left covers nothing any more
        return entry.frame.index
