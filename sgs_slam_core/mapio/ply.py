"""PLY files: the standard 3DGS splat layout (SuperSplat & co.) and plain coloured point clouds.

The splat file has the usual ``x y z nx ny nz f_dc_0..2 opacity scale_0..2 rot_0..3`` (colour as
the SH DC term (c - 0.5) / C0, opacity as a logit, log scales, wxyz rotation) plus our own
``label``, ``birth_frame``, ``sem_0..S-1`` and the raw colours ``raw_r/g/b``; header comments carry
the label table and whether the map is isotropic, so :func:`read_splat_ply` restores our maps
exactly. PLYs from other 3DGS tools import as anisotropic maps without semantics.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import torch

from sgs_slam_core.errors import MapFileError
from sgs_slam_core.fileio import atomic_write, read_bytes
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.labels import MAX_CLASS_ID, LabelError, LabelTable
from sgs_slam_core.validate import as_int

__all__ = ["SH_C0", "read_splat_ply", "write_map_point_cloud", "write_point_cloud_ply", "write_splat_ply"]

SH_C0 = 0.28209479177387814
_PLY_TYPES = {
    "float": "<f4", "float32": "<f4", "double": "<f8", "float64": "<f8", "int": "<i4", "int32": "<i4",
    "uint": "<u4", "uint32": "<u4", "short": "<i2", "int16": "<i2", "ushort": "<u2", "uint16": "<u2",
    "uchar": "u1", "uint8": "u1", "char": "i1", "int8": "i1",
}  # fmt: skip
_NAMES = {np.dtype("<f4"): "float", np.dtype("<i4"): "int", np.dtype("u1"): "uchar", np.dtype("<f8"): "double"}


def _write(path: Path, data: np.ndarray, comments: list[str]) -> None:
    header = ["ply", "format binary_little_endian 1.0", *(f"comment {c}" for c in comments)]
    header.append(f"element vertex {len(data)}")
    header += [f"property {_NAMES[data.dtype.fields[n][0]]} {n}" for n in data.dtype.names]
    header.append("end_header")
    blob = ("\n".join(header) + "\n").encode("ascii") + data.tobytes()
    atomic_write(path, lambda f: f.write(blob))


def write_splat_ply(path: str | Path, gaussians: GaussianMap, table: LabelTable | None = None) -> None:
    """Export in the 3DGS layout (plus semantic fields); written atomically."""
    g = gaussians.detach().to("cpu")
    n, s = len(g), g.num_semantic
    fields = [
        (c, "<f4")
        for c in (
            "x",
            "y",
            "z",
            "nx",
            "ny",
            "nz",
            "f_dc_0",
            "f_dc_1",
            "f_dc_2",
            "opacity",
            "scale_0",
            "scale_1",
            "scale_2",
            "rot_0",
            "rot_1",
            "rot_2",
            "rot_3",
        )
    ]
    fields += [("label", "<i4"), ("birth_frame", "<i4"), ("raw_r", "<f4"), ("raw_g", "<f4"), ("raw_b", "<f4")]
    fields += [(f"sem_{i}", "<f4") for i in range(s)]
    data = np.zeros(n, dtype=np.dtype(fields))
    means = g.means.float().numpy()
    data["x"], data["y"], data["z"] = means.T
    colors = g.colors.float().numpy()
    for i in range(3):
        data[f"f_dc_{i}"] = (colors[:, i] - 0.5) / SH_C0
        data[("raw_r", "raw_g", "raw_b")[i]] = colors[:, i]
    data["opacity"] = g.logit_opacities.float().numpy()
    scales = g.log_scales.float().numpy()
    for i in range(3):
        data[f"scale_{i}"] = scales[:, 0] if g.isotropic else scales[:, i]
    quats = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)) if g.quats is None else g.quats.float().numpy()
    for i in range(4):
        data[f"rot_{i}"] = quats[:, i]
    data["label"] = g.labels.numpy()
    data["birth_frame"] = g.birth_frame.numpy()
    sem = g.semantics.float().numpy()
    for i in range(s):
        data[f"sem_{i}"] = sem[:, i]
    comments = [f"sgs_slam_isotropic {int(g.isotropic)}"]
    if table is not None:
        comments.append("sgs_slam_labels " + json.dumps(table.to_dict(), separators=(",", ":")))
    _write(Path(path), data, comments)


def _header(path: Path, lines: list[str]) -> tuple[int, list[tuple[str, str]]]:
    """``(vertex count, [(property, numpy type)])`` of a PLY header; the vertex element must come first."""
    count, props, element = -1, [], None
    for lineno, ln in enumerate(lines, 1):
        parts = ln.split()
        if parts[:1] == ["element"]:
            if len(parts) != 3:
                raise MapFileError(f"{path}: header line {lineno} {ln!r}: expected 'element NAME COUNT'")
            if element is None and parts[1] != "vertex":
                raise MapFileError(f"{path}: the first element is {parts[1]!r}; a splat PLY starts with 'vertex'")
            element = parts[1]
            if element == "vertex":
                count = as_int(parts[2], f"{path}: header line {lineno}: vertex count", MapFileError, 0)
        elif parts[:1] == ["property"] and element == "vertex":
            if len(parts) != 3 or parts[1] == "list" or parts[1] not in _PLY_TYPES:
                raise MapFileError(f"{path}: header line {lineno}: unsupported property {' '.join(parts[1:])!r}")
            if any(name == parts[2] for name, _ in props):
                raise MapFileError(f"{path}: header line {lineno}: property {parts[2]!r} appears twice")
            props.append((parts[2], _PLY_TYPES[parts[1]]))
    if count < 0:
        raise MapFileError(f"{path}: the header has no 'element vertex' line")
    if not props:
        raise MapFileError(f"{path}: the vertex element has no properties")
    return count, props


def _read(path: Path) -> tuple[np.ndarray, list[str]]:
    raw = read_bytes(path, "map file", MapFileError)
    end = raw.find(b"end_header\n")
    if not raw.startswith(b"ply") or end < 0:
        raise MapFileError(f"{path} is not a PLY file (no header)")
    lines = raw[:end].decode("ascii", errors="replace").splitlines()
    if "format binary_little_endian 1.0" not in lines:
        raise MapFileError(f"{path}: only binary little-endian PLY is supported")
    comments = [ln[len("comment ") :] for ln in lines if ln.startswith("comment ")]
    count, props = _header(path, lines)
    dtype = np.dtype(props)
    body = raw[end + len(b"end_header\n") :]
    if len(body) < count * dtype.itemsize:
        raise MapFileError(
            f"{path} is truncated: {count} vertices need {count * dtype.itemsize} bytes, found {len(body)}"
        )
    return np.frombuffer(body, dtype=dtype, count=count), comments


def _label_table(path: Path, meta: dict[str, str]) -> LabelTable | None:
    if "sgs_slam_labels" not in meta:
        return None
    try:
        return LabelTable.from_dict(json.loads(meta["sgs_slam_labels"]))
    except (json.JSONDecodeError, LabelError) as err:
        raise MapFileError(f"{path}: the label table in the header is malformed: {err}") from err


def _check_values(path: Path, data: np.ndarray, names: set[str]) -> None:
    """Finite Gaussian parameters and class ids in range; anything else names the property."""
    for name in sorted(names):
        values = data[name]
        if np.issubdtype(values.dtype, np.floating) and not np.isfinite(values).all():
            bad = int((~np.isfinite(values)).sum())
            raise MapFileError(f"{path}: property {name!r} holds {bad} NaN or infinite values")
    if "label" in names and len(data):
        labels = data["label"]
        if np.issubdtype(labels.dtype, np.floating) and not (labels == np.round(labels)).all():
            raise MapFileError(f"{path}: property 'label' holds non-integer class ids")
        if labels.min() < 0 or labels.max() > MAX_CLASS_ID:
            raise MapFileError(f"{path}: property 'label' holds ids outside 0..{MAX_CLASS_ID}")


def read_splat_ply(path: str | Path) -> tuple[GaussianMap, LabelTable | None]:
    """Import a splat PLY (ours exactly; other tools' as anisotropic maps without semantics)."""
    path = Path(path)
    data, comments = _read(path)
    names = set(data.dtype.names or ())
    need = {"x", "y", "z", "opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"}
    if not need <= names:
        raise MapFileError(f"{path}: not a Gaussian-splat PLY, missing {sorted(need - names)}")
    meta = dict(c.split(" ", 1) for c in comments if " " in c)
    isotropic = meta.get("sgs_slam_isotropic") == "1"
    table = _label_table(path, meta)
    sem_keys = sorted((k for k in names if re.fullmatch(r"sem_\d+", k)), key=lambda k: int(k[4:]))
    _check_values(path, data, need | {"label"} & names | set(sem_keys))

    def col(*keys: str) -> torch.Tensor:
        return torch.from_numpy(np.stack([data[k] for k in keys], axis=1).astype(np.float32))

    n = len(data)
    if {"raw_r", "raw_g", "raw_b"} <= names:
        colors = col("raw_r", "raw_g", "raw_b")
    elif {"f_dc_0", "f_dc_1", "f_dc_2"} <= names:
        colors = col("f_dc_0", "f_dc_1", "f_dc_2") * SH_C0 + 0.5
    else:
        colors = torch.full((n, 3), 0.5, device="cpu")
    semantics = col(*sem_keys) if sem_keys else torch.zeros(n, 0, device="cpu")
    scales = col("scale_0", "scale_1", "scale_2")
    return GaussianMap(
        means=col("x", "y", "z"),
        log_scales=scales[:, :1].clone() if isotropic else scales,
        logit_opacities=torch.from_numpy(data["opacity"].astype(np.float32)),
        colors=colors,
        semantics=semantics,
        labels=torch.from_numpy(data["label"].astype(np.int64))
        if "label" in names
        else torch.zeros(n, dtype=torch.long, device="cpu"),
        birth_frame=torch.from_numpy(data["birth_frame"].astype(np.int64))
        if "birth_frame" in names
        else torch.zeros(n, dtype=torch.long, device="cpu"),
        quats=None if isotropic else col("rot_0", "rot_1", "rot_2", "rot_3"),
    ), table


def write_point_cloud_ply(
    path: str | Path, points: np.ndarray, colors: np.ndarray, labels: np.ndarray | None = None
) -> None:
    """A plain coloured point cloud (``x y z red green blue [label]``) for MeshLab / CloudCompare."""
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")]
    if labels is not None:
        fields.append(("label", "<i4"))
    data = np.zeros(len(points), dtype=np.dtype(fields))
    data["x"], data["y"], data["z"] = np.asarray(points, np.float32).T
    data["red"], data["green"], data["blue"] = np.asarray(colors, np.uint8).T
    if labels is not None:
        data["label"] = labels
    _write(Path(path), data, ["sgs_slam point cloud"])


def write_map_point_cloud(
    path: str | Path, gaussians: GaussianMap, table: LabelTable, semantic: bool = False, min_opacity: float = 0.5
) -> int:
    """The Gaussian centres as a coloured point cloud (colour, or class palette colour with ``semantic``).

    Gaussians below ``min_opacity`` are left out; returns the number of points written.
    """
    g = gaussians.detach().to("cpu")
    keep = (g.opacities >= min_opacity).numpy()
    labels = g.labels.numpy()[keep]
    if semantic:
        colors = table.colorize(labels)
    else:
        colors = np.round(g.colors.clamp(0.0, 1.0).numpy()[keep] * 255.0).astype(np.uint8)
    write_point_cloud_ply(path, g.means.numpy()[keep], colors, labels)
    return int(keep.sum())
