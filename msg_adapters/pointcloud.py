"""sensor_msgs/PointCloud2 <-> numpy structured arrays (points for RViz, full Gaussian maps)."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from msg_adapters.errors import AdapterError
from msg_adapters.stamps import ns_to_stamp
from sgs_slam_core.errors import ShapeError
from sgs_slam_core.gaussians import GaussianMap

__all__ = [
    "GAUSSIAN_FIELDS",
    "POINT_DTYPE",
    "gaussian_dtype",
    "gaussians_from_cloud",
    "gaussians_to_cloud",
    "pack_rgb",
    "pointcloud_fields",
    "pointcloud_to_numpy",
    "unpack_rgb",
]

# PointField datatypes
_PF = {1: "i1", 2: "u1", 3: "<i2", 4: "<u2", 5: "<i4", 6: "<u4", 7: "<f4", 8: "<f8"}
_NP = {np.dtype(v): k for k, v in _PF.items()}

POINT_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("rgb", "<f4"), ("label", "<u4")])
GAUSSIAN_FIELDS = ("x", "y", "z", "opacity", "r", "g", "b", "label", "birth_frame")


def pack_rgb(rgb: np.ndarray) -> np.ndarray:  # [N, 3] uint8 -> [N] float32
    """PCL/RViz packing: 0x00RRGGBB reinterpreted as float32."""
    rgb = np.asarray(rgb, dtype=np.uint32)
    return ((rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]).astype(np.uint32).view(np.float32)


def unpack_rgb(packed: np.ndarray) -> np.ndarray:  # [N] float32 -> [N, 3] uint8
    """Inverse of :func:`pack_rgb`."""
    v = np.ascontiguousarray(packed, dtype=np.float32).view(np.uint32)
    return np.stack([(v >> 16) & 255, (v >> 8) & 255, v & 255], axis=1).astype(np.uint8)


def pointcloud_fields(points: np.ndarray, stamp_ns: int, frame_id: str) -> dict[str, Any]:
    """Field values of an unorganised PointCloud2 holding a structured array (``data`` as bytes)."""
    if points.dtype.names is None:
        raise AdapterError("data: points must be a numpy structured array")
    fields = []
    for name in points.dtype.names:
        dt, offset = points.dtype.fields[name][:2]
        if dt.base not in _NP:
            raise AdapterError(f"fields: {name} has unsupported dtype {dt}")
        fields.append({"name": name, "offset": int(offset), "datatype": _NP[dt.base], "count": 1})
    finite = all(np.isfinite(points[n]).all() for n in ("x", "y", "z") if n in points.dtype.names)
    sec, nanosec = ns_to_stamp(stamp_ns)
    return {
        "header": {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": frame_id},
        "height": 1,
        "width": int(points.shape[0]),
        "fields": fields,
        "is_bigendian": False,
        "point_step": int(points.dtype.itemsize),
        "row_step": int(points.dtype.itemsize * points.shape[0]),
        "data": np.ascontiguousarray(points).tobytes(),
        "is_dense": bool(finite),
    }


def pointcloud_to_numpy(msg: Any) -> np.ndarray:
    """The points of a PointCloud2 (any flavour) as a structured array with the message's fields."""
    if msg.is_bigendian:
        raise AdapterError("is_bigendian: big-endian point clouds are not supported")
    names, formats, offsets = [], [], []
    for f in msg.fields:
        if int(f.datatype) not in _PF:
            raise AdapterError(f"fields: {f.name} has unknown datatype {f.datatype}")
        if int(getattr(f, "count", 1)) != 1:
            raise AdapterError(f"fields: {f.name} has count {f.count}; only scalar fields are supported")
        names.append(str(f.name))
        formats.append(_PF[int(f.datatype)])
        offsets.append(int(f.offset))
    dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": int(msg.point_step)})
    n = int(msg.width) * int(msg.height)
    buf = np.frombuffer(msg.data, dtype=np.uint8)
    if buf.size < n * dtype.itemsize:
        raise AdapterError(f"data: {buf.size} bytes for {n} points of {dtype.itemsize} bytes")
    return np.frombuffer(buf[: n * dtype.itemsize].tobytes(), dtype=dtype, count=n)


def gaussian_dtype(num_semantic: int, isotropic: bool) -> np.dtype:
    """Fields of a full Gaussian map cloud: every parameter, pre-activation, exactly."""
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    fields += [("scale", "<f4")] if isotropic else [("scale_0", "<f4"), ("scale_1", "<f4"), ("scale_2", "<f4")]
    if not isotropic:
        fields += [("rot_0", "<f4"), ("rot_1", "<f4"), ("rot_2", "<f4"), ("rot_3", "<f4")]
    fields += [("opacity", "<f4"), ("r", "<f4"), ("g", "<f4"), ("b", "<f4")]
    fields += [(f"sem_{i}", "<f4") for i in range(num_semantic)]
    fields += [("label", "<i4"), ("birth_frame", "<i4")]
    return np.dtype(fields)


def gaussians_to_cloud(gaussians: GaussianMap) -> np.ndarray:
    """Structured array with every Gaussian field (log scales, logit opacities, raw colours)."""
    g = gaussians.detach().to("cpu")
    arr = np.zeros(len(g), dtype=gaussian_dtype(g.num_semantic, g.isotropic))
    means = g.means.float().numpy()
    arr["x"], arr["y"], arr["z"] = means.T
    scales = g.log_scales.float().numpy()
    if g.isotropic:
        arr["scale"] = scales[:, 0]
    else:
        for i in range(3):
            arr[f"scale_{i}"] = scales[:, i]
        for i in range(4):
            arr[f"rot_{i}"] = g.quats.float().numpy()[:, i]  # type: ignore[union-attr]
    arr["opacity"] = g.logit_opacities.float().numpy()
    colors = g.colors.float().numpy()
    arr["r"], arr["g"], arr["b"] = colors.T
    sem = g.semantics.float().numpy()
    for i in range(g.num_semantic):
        arr[f"sem_{i}"] = sem[:, i]
    arr["label"] = g.labels.numpy()
    arr["birth_frame"] = g.birth_frame.numpy()
    return arr


def gaussians_from_cloud(arr: np.ndarray, device: torch.device | str = "cpu") -> GaussianMap:
    """Inverse of :func:`gaussians_to_cloud` (exact for float32 maps)."""
    names = set(arr.dtype.names or ())
    missing = {"x", "y", "z", "opacity", "r", "g", "b", "label", "birth_frame"} - names
    if missing or not ({"scale"} <= names or {"scale_0", "scale_1", "scale_2"} <= names):
        raise AdapterError(f"fields: not a Gaussian map cloud, missing {sorted(missing) or ['scale']}")

    def col(*keys: str) -> torch.Tensor:
        return torch.from_numpy(np.stack([np.asarray(arr[k], dtype=np.float32) for k in keys], axis=1))

    isotropic = "scale" in names
    sem_keys = sorted((k for k in names if k.startswith("sem_")), key=lambda k: int(k[4:]))
    n = arr.shape[0]
    try:
        g = GaussianMap(
            means=col("x", "y", "z"),
            log_scales=col("scale") if isotropic else col("scale_0", "scale_1", "scale_2"),
            logit_opacities=torch.from_numpy(np.asarray(arr["opacity"], dtype=np.float32).copy()),
            colors=col("r", "g", "b"),
            semantics=col(*sem_keys) if sem_keys else torch.zeros(n, 0, device="cpu"),
            labels=torch.from_numpy(np.asarray(arr["label"], dtype=np.int64)),
            birth_frame=torch.from_numpy(np.asarray(arr["birth_frame"], dtype=np.int64)),
            quats=None if isotropic else col("rot_0", "rot_1", "rot_2", "rot_3"),
        )
    except ShapeError as err:
        raise AdapterError(f"fields: {err}") from err
    return g.to(device)
