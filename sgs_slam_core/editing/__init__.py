"""Object-level scene editing: every Gaussian knows its class, so objects can be removed or moved."""

from sgs_slam_core.editing.operations import (
    EditKind,
    EditRecord,
    euler_deg_to_matrix,
    keep_only,
    move,
    recolor,
    remove,
)
from sgs_slam_core.editing.request import EditRequest, apply_edit
from sgs_slam_core.editing.selection import EditError, Selection, connected_instances, label_summary, select

__all__ = [
    "EditError",
    "EditKind",
    "EditRecord",
    "EditRequest",
    "Selection",
    "apply_edit",
    "connected_instances",
    "euler_deg_to_matrix",
    "keep_only",
    "label_summary",
    "move",
    "recolor",
    "remove",
    "select",
]
