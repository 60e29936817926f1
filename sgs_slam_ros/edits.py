"""Map edits requested through the mapping node's ``edit.*`` parameters."""

from __future__ import annotations

import math

from sgs_slam_core.editing import EditError, EditKind, EditRequest, Selection
from sgs_slam_ros.params import NodeParams

__all__ = ["requested_edits"]


def _label(text: str) -> int | str:
    text = text.strip()
    return int(text) if text.lstrip("-").isdigit() else text


def _vector(params: NodeParams, name: str) -> tuple[float, float, float]:
    values = [float(v) for v in params[name]]
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise EditError(f"{name} needs 3 finite numbers, got {values}")
    return values[0], values[1], values[2]


def requested_edits(params: NodeParams) -> list[EditRequest]:
    """The edits the parameters describe now: a removal, then a move (either may be absent)."""
    instance = int(params["edit.instance"])
    pick = None if instance < 0 else instance
    edits = []
    remove = [_label(t) for t in params["edit.remove_labels"]]
    if remove:
        edits.append(EditRequest(EditKind.REMOVE, Selection(tuple(remove), instance=pick)))
    move = str(params["edit.move_label"]).strip()
    if move:
        translation, rotation = _vector(params, "edit.translation"), _vector(params, "edit.rotation_deg")
        edits.append(EditRequest(EditKind.MOVE, Selection((_label(move),), instance=pick), translation, rotation))
    if not edits:
        raise EditError("nothing to apply: set edit.remove_labels and/or edit.move_label first")
    return edits
