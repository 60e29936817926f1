"""Which Gaussians an edit applies to: classes, an optional box, an optional connected instance."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from sgs_slam_core.errors import EditError
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.labels import LabelTable

__all__ = ["EditError", "Selection", "connected_instances", "label_summary", "select"]


@dataclass(frozen=True)
class Selection:
    """What to edit.

    Attributes:
        labels: class ids or names (several allowed).
        box: optional axis-aligned world box ``((xmin, ymin, zmin), (xmax, ymax, zmax))`` in metres.
        instance: pick one connected object among the selected Gaussians (0 = the largest, 1 = the
            next, ...); None takes them all. Connectivity: centres closer than ``link_m``.
        link_m: distance (m) under which two Gaussians belong to the same instance.
    """

    labels: tuple[int | str, ...]
    box: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    instance: int | None = None
    link_m: float = 0.05

    def __post_init__(self) -> None:
        if not self.labels:
            raise EditError("select at least one class")
        if self.instance is not None and self.instance < 0:
            raise EditError(f"instance must be >= 0, got {self.instance}")
        if not self.link_m > 0:
            raise EditError(f"link_m must be > 0, got {self.link_m}")


def connected_instances(points: np.ndarray, link_m: float) -> np.ndarray:  # [M, 3] -> [M] component id, 0 = largest
    """Connected components of points under a voxel adjacency of ``link_m`` (26-neighbourhood).

    Points in the same or adjacent voxels of side ``link_m`` are linked, so objects closer than
    ``link_m`` merge and objects farther than ``2 * sqrt(3) * link_m`` never do.
    """
    if len(points) == 0:
        return np.zeros(0, dtype=np.int64)
    vox = np.floor(points / link_m).astype(np.int64)
    keys, inverse = np.unique(vox, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    n = len(keys)
    span = keys.max(0) - keys.min(0) + 3
    base = keys - keys.min(0) + 1

    def code(v: np.ndarray) -> np.ndarray:
        return (v[:, 0] * span[1] + v[:, 1]) * span[2] + v[:, 2]

    codes = code(base)
    order = np.argsort(codes)
    sorted_codes = codes[order]
    edges_a, edges_b = [], []
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            for dz in (-1, 0, 1):
                if (dx, dy, dz) <= (0, 0, 0):
                    continue  # each undirected neighbour pair once
                q = code(base + np.array([dx, dy, dz]))
                pos = np.clip(np.searchsorted(sorted_codes, q), 0, n - 1)
                hit = sorted_codes[pos] == q
                edges_a.append(np.nonzero(hit)[0])
                edges_b.append(order[pos[hit]])
    a, b = np.concatenate(edges_a), np.concatenate(edges_b)
    comp = np.arange(n)
    while True:  # label propagation: every voxel takes the smallest id of its neighbours
        m = np.minimum(comp[a], comp[b])
        new = comp.copy()
        np.minimum.at(new, a, m)
        np.minimum.at(new, b, m)
        new = new[new]
        if np.array_equal(new, comp):
            break
        comp = new
    ids, per_voxel = np.unique(comp, return_inverse=True)
    sizes = np.bincount(per_voxel[inverse], minlength=len(ids))
    rank = np.empty(len(ids), dtype=np.int64)
    rank[np.argsort(-sizes, kind="stable")] = np.arange(len(ids))
    return rank[per_voxel[inverse]]


def select(gaussians: GaussianMap, selection: Selection, table: LabelTable | None = None) -> Tensor:  # [N] bool
    """Boolean mask of the selected Gaussians (raises if nothing is selected)."""
    table = table or LabelTable.nyu40()
    try:
        ids = sorted({table.id_of(label) for label in selection.labels})
    except KeyError as err:
        raise EditError(str(err)) from err
    labels = gaussians.labels
    mask = torch.isin(labels, torch.tensor(ids, dtype=labels.dtype, device=labels.device))
    if selection.box is not None:
        lo = torch.tensor(selection.box[0], dtype=gaussians.means.dtype, device=gaussians.device)
        hi = torch.tensor(selection.box[1], dtype=gaussians.means.dtype, device=gaussians.device)
        mask &= ((gaussians.means >= lo) & (gaussians.means <= hi)).all(dim=1)
    if selection.instance is not None and bool(mask.any()):
        idx = torch.nonzero(mask).squeeze(1)
        comps = connected_instances(gaussians.means[idx].detach().cpu().numpy(), selection.link_m)
        if selection.instance >= comps.max() + 1:
            raise EditError(
                f"instance {selection.instance} requested but the selection has {comps.max() + 1} instances"
            )
        keep = torch.from_numpy(comps == selection.instance).to(mask.device)
        mask = torch.zeros_like(mask)
        mask[idx[keep]] = True
    if not bool(mask.any()):
        names = ", ".join(f"{i} ({table.name_of(i)})" for i in ids)
        raise EditError(f"no Gaussian matches class {names}" + (" in the box" if selection.box else ""))
    return mask


def label_summary(gaussians: GaussianMap, table: LabelTable) -> list[tuple[int, str, int, np.ndarray, np.ndarray]]:
    """(id, name, Gaussian count, bbox min [3], bbox max [3]) per class present in the map."""
    out = []
    labels = gaussians.labels.cpu()
    means = gaussians.means.detach().cpu().numpy()
    for class_id in sorted(int(i) for i in labels.unique()):
        sel = (labels == class_id).numpy()
        pts = means[sel]
        out.append((class_id, table.name_of(class_id), int(sel.sum()), pts.min(0), pts.max(0)))
    return out
