"""Edits of a live map: the classes they lock and how to undo them while mapping goes on.

An applied edit *locks* its classes until it is undone: pixels labelled with a locked class are
ignored by tracking, densification and mapping (so a removed object does not grow back when the
camera sees it again, and a moved one is not re-created where it stood), and Gaussians of a locked
class are frozen (never optimised, pruned or relabelled). Frames without labels cannot be masked.

Because locked Gaussians are frozen and no new Gaussian of a locked class is ever added, the rows
of those classes are, at undo time, exactly the rows they were right after the edit, in order.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import torch
from torch import Tensor

from sgs_slam_core.editing import EditError, EditKind, EditRecord, EditRequest, apply_edit
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.labels import LabelTable

__all__ = ["EditLocks"]


@dataclass(frozen=True)
class _Applied:
    record: EditRecord
    locked: frozenset[int]
    removed: GaussianMap | None  # REMOVE/KEEP: the Gaussians taken out, re-added by undo
    label_rows: int  # rows of the locked classes right after the edit
    moved: Tensor | None  # [label_rows] bool, MOVE/RECOLOR: which of those rows the edit changed
    before: GaussianMap | None  # MOVE/RECOLOR: the changed rows as they were before


class EditLocks:
    """The stack of edits applied to a live map (undo is last-in first-out)."""

    def __init__(self, locked: frozenset[int] = frozenset()) -> None:
        self._stack: list[_Applied] = []
        self._base = frozenset(int(i) for i in locked)  # locks loaded with a saved map (no undo record)

    @property
    def locked_labels(self) -> frozenset[int]:
        """Classes whose pixels are ignored and whose Gaussians are frozen."""
        out = set(self._base)
        for applied in self._stack:
            out |= applied.locked
        return frozenset(out)

    @property
    def depth(self) -> int:
        """Edits that can be undone."""
        return len(self._stack)

    def apply(self, gaussians: GaussianMap, request: EditRequest, table: LabelTable) -> tuple[GaussianMap, EditRecord]:
        """Apply ``request`` and lock the classes it touched."""
        out, record = apply_edit(gaussians, request, table)
        locked = frozenset(record.labels)
        rows_after = torch.isin(out.labels, _ids(locked, out.labels))
        if request.kind in (EditKind.REMOVE, EditKind.KEEP):
            applied = _Applied(record, locked, gaussians.select(record.selected), int(rows_after.sum()), None, None)
        else:
            rows_before = torch.isin(gaussians.labels, _ids(locked, gaussians.labels))
            moved = record.selected[rows_before]
            applied = _Applied(record, locked, None, int(rows_before.sum()), moved, gaussians.select(record.selected))
        self._stack.append(applied)
        return out, record

    def undo(self, gaussians: GaussianMap) -> tuple[GaussianMap, EditRecord]:
        """Revert the last edit on the current map (mapping done since is kept) and unlock its classes."""
        if not self._stack:
            raise EditError("no edit to undo")
        applied = self._stack[-1]
        rows = torch.nonzero(torch.isin(gaussians.labels, _ids(applied.locked, gaussians.labels))).squeeze(1)
        if applied.removed is not None:
            out = gaussians.cat(applied.removed.to(gaussians.device))
        else:
            assert applied.moved is not None and applied.before is not None
            if len(rows) != applied.label_rows:
                raise EditError(f"the edited classes have {len(rows)} Gaussians, {applied.label_rows} expected")
            changed = rows[applied.moved.to(rows.device)]
            out = _put_rows(gaussians, changed, applied.before.to(gaussians.device))
        self._stack.pop()
        return out, applied.record

    def clear(self) -> None:
        """Forget every edit and unlock every class (the map is left as it is)."""
        self._stack.clear()
        self._base = frozenset()

    def ignore_mask(self, labels: Tensor | None) -> Tensor | None:  # [H, W] int64 -> [H, W] bool
        """Pixels to ignore (labelled with a locked class); None when nothing is locked or unlabelled."""
        locked = self.locked_labels
        if labels is None or not locked:
            return None
        return torch.isin(labels, _ids(locked, labels))


def _ids(labels: frozenset[int], like: Tensor) -> Tensor:
    return torch.tensor(sorted(labels), dtype=torch.int64, device=like.device)


def _put_rows(gaussians: GaussianMap, rows: Tensor, values: GaussianMap) -> GaussianMap:
    """``gaussians`` with ``rows`` [M] replaced by the M Gaussians of ``values``."""
    replaced = {}
    for f in fields(GaussianMap):
        current = getattr(gaussians, f.name)
        if current is not None:
            replaced[f.name] = current.detach().clone().index_copy_(0, rows, getattr(values, f.name).to(current))
    return GaussianMap(**replaced)
