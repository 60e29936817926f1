"""An edit as data (what the CLI and the ROS services build), and the one function that applies it."""

from __future__ import annotations

from dataclasses import dataclass

from sgs_slam_core.editing.operations import EditKind, EditRecord, keep_only, move, recolor, remove
from sgs_slam_core.editing.selection import EditError, Selection
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.labels import LabelTable

__all__ = ["EditKind", "EditRequest", "apply_edit"]


@dataclass(frozen=True)
class EditRequest:
    """One edit: an operation on a selection, with its parameters.

    Attributes:
        kind: the operation.
        selection: which Gaussians.
        translation: metres, world frame (MOVE).
        rotation_deg: rotation about world x, y, z in degrees, applied about ``pivot`` (MOVE).
        pivot: world point (m) to rotate about; None = the selection's centroid (MOVE).
        rgb: new colour in [0, 1] (RECOLOR).
    """

    kind: EditKind
    selection: Selection
    translation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotation_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    pivot: tuple[float, float, float] | None = None
    rgb: tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        if len(self.translation) != 3 or len(self.rotation_deg) != 3:
            raise EditError("translation and rotation_deg need 3 numbers each")
        if self.pivot is not None and len(self.pivot) != 3:
            raise EditError("pivot needs 3 numbers")
        if self.kind is EditKind.RECOLOR and (self.rgb is None or len(self.rgb) != 3):
            raise EditError("recolour needs an rgb colour (3 numbers in [0, 1])")


def apply_edit(
    gaussians: GaussianMap, request: EditRequest, table: LabelTable | None = None
) -> tuple[GaussianMap, EditRecord]:
    """Apply ``request`` to ``gaussians``; returns the new map and what changed (input untouched)."""
    if request.kind is EditKind.REMOVE:
        return remove(gaussians, request.selection, table)
    if request.kind is EditKind.KEEP:
        return keep_only(gaussians, request.selection, table)
    if request.kind is EditKind.MOVE:
        return move(gaussians, request.selection, request.translation, request.rotation_deg, request.pivot, table)
    assert request.rgb is not None  # checked in __post_init__
    return recolor(gaussians, request.selection, request.rgb, table)
