"""Edits of a Gaussian map by object; each returns a new map and a record (the input is untouched)."""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field

import numpy as np
import torch

from sgs_slam_core.editing.selection import EditError, Selection, select
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.geometry.se3 import se3_from_rt, so3_exp
from sgs_slam_core.labels import LabelTable

__all__ = ["EditKind", "EditRecord", "euler_deg_to_matrix", "keep_only", "move", "recolor", "remove"]


class EditKind(enum.Enum):
    """The operations an edit can perform."""

    REMOVE = "remove"
    KEEP = "keep"
    MOVE = "move"
    RECOLOR = "recolor"


@dataclass(frozen=True)
class EditRecord:
    """What an edit did."""

    kind: EditKind
    labels: tuple[int, ...]  # classes of the affected Gaussians
    count: int  # Gaussians affected
    before: int  # Gaussians in the map before
    after: int  # and after
    selected: torch.Tensor = field(repr=False, compare=False)  # [before] bool, the affected Gaussians of the input
    transform: np.ndarray | None = None  # [4, 4] world transform applied (move)
    pivot: tuple[float, float, float] | None = None  # m, the rotation centre (move)

    def summary(self) -> str:
        """One line for logs and service responses."""
        text = (
            f"{self.kind.value}: {self.count} Gaussians of classes {list(self.labels)} ({self.before} -> {self.after})"
        )
        if self.transform is not None:
            t = self.transform[:3, 3]
            text += f", transform translation [{t[0]:.3f}, {t[1]:.3f}, {t[2]:.3f}] m"
        return text


def _ids(gaussians: GaussianMap, mask: torch.Tensor) -> tuple[int, ...]:
    return tuple(sorted(int(i) for i in gaussians.labels[mask].unique()))


def remove(
    gaussians: GaussianMap, selection: Selection, table: LabelTable | None = None
) -> tuple[GaussianMap, EditRecord]:
    """Delete the selected Gaussians; every other Gaussian is kept bit-identical and in order."""
    mask = select(gaussians, selection, table)
    out = gaussians.prune(mask)
    return out, EditRecord(EditKind.REMOVE, _ids(gaussians, mask), int(mask.sum()), len(gaussians), len(out), mask)


def keep_only(
    gaussians: GaussianMap, selection: Selection, table: LabelTable | None = None
) -> tuple[GaussianMap, EditRecord]:
    """Keep only the selected Gaussians (the record lists what was dropped)."""
    mask = select(gaussians, selection, table)
    out = gaussians.select(mask)
    dropped = ~mask
    return out, EditRecord(
        EditKind.KEEP, _ids(gaussians, dropped), int(dropped.sum()), len(gaussians), len(out), dropped
    )


def euler_deg_to_matrix(rx: float, ry: float, rz: float) -> np.ndarray:  # [3, 3]
    """Rotation R = Rz(rz) Ry(ry) Rx(rx) from angles in degrees about the world x, y, z axes."""

    def axis(a: int, deg: float) -> torch.Tensor:
        v = torch.zeros(3, dtype=torch.float64, device="cpu")
        v[a] = math.radians(deg)
        return so3_exp(v)

    return (axis(2, rz) @ axis(1, ry) @ axis(0, rx)).numpy()


def move(
    gaussians: GaussianMap,
    selection: Selection,
    translation: tuple[float, float, float] = (0.0, 0.0, 0.0),
    rotation_deg: tuple[float, float, float] = (0.0, 0.0, 0.0),
    pivot: tuple[float, float, float] | None = None,
    table: LabelTable | None = None,
) -> tuple[GaussianMap, EditRecord]:
    """Rotate the selection about ``pivot`` (default: its centroid), then translate it (m).

    Isotropic Gaussians need only their centres moved; anisotropic ones are rotated too.
    """
    mask = select(gaussians, selection, table)
    if pivot is None:
        pivot = tuple(float(v) for v in gaussians.means[mask].detach().double().mean(0).cpu())
    rot = euler_deg_to_matrix(*rotation_deg)
    c = np.asarray(pivot, dtype=np.float64)
    t = np.asarray(translation, dtype=np.float64) + c - rot @ c
    pose = se3_from_rt(torch.from_numpy(rot), torch.from_numpy(t))
    if not torch.isfinite(pose).all():
        raise EditError("translation and rotation must be finite")
    out = gaussians.transformed(pose.to(gaussians.means.dtype), mask)
    record = EditRecord(
        EditKind.MOVE,
        _ids(gaussians, mask),
        int(mask.sum()),
        len(gaussians),
        len(out),
        mask,
        pose.numpy(),
        (float(c[0]), float(c[1]), float(c[2])),
    )
    return out, record


def recolor(
    gaussians: GaussianMap, selection: Selection, rgb: tuple[float, float, float], table: LabelTable | None = None
) -> tuple[GaussianMap, EditRecord]:
    """Paint the selection (colour in [0, 1])."""
    if not all(0.0 <= v <= 1.0 for v in rgb):
        raise EditError(f"colour must be in [0, 1], got {rgb}")
    mask = select(gaussians, selection, table)
    colors = gaussians.colors.clone()
    colors[mask] = torch.tensor(rgb, dtype=colors.dtype, device=colors.device)
    out = gaussians.with_tensors(colors=colors)
    return out, EditRecord(EditKind.RECOLOR, _ids(gaussians, mask), int(mask.sum()), len(gaussians), len(out), mask)
