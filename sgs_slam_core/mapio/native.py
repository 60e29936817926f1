"""The native map file: everything needed to resume mapping, written atomically and validated on load.

Contents (a ``torch.save`` dict, loadable with ``weights_only=True``): format tag and version, the
Gaussian tensors, the label table, the resolved config, the intrinsics, the keyframe poses, the
estimated trajectory, and optionally the images of the most recent keyframes the store holds (uint8
colour, uint16 depth, labels in the smallest type that holds them: 1.8 MB per 640x480 keyframe with
uint8 labels) so that mapping resumes with its window.
"""

from __future__ import annotations

import contextlib
import io
import pickle
import zipfile
from collections.abc import Callable
from contextlib import AbstractContextManager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
import torch

from sgs_slam_core.errors import MapFileError, ShapeError
from sgs_slam_core.fileio import atomic_write
from sgs_slam_core.frame import CompactFrame, compact_labels
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.labels import LabelError, LabelTable
from sgs_slam_core.validate import as_float, as_int

__all__ = ["FORMAT", "VERSION", "MapFile", "load_map", "save_map"]

FORMAT = "sgs-slam-map"
VERSION = 1
_REQUIRED = ("format", "version", "gaussians", "label_table", "config", "intrinsics", "keyframes", "trajectory")


@dataclass
class MapFile:
    """A saved map and its context."""

    gaussians: GaussianMap
    label_table: LabelTable
    config: dict[str, Any] = field(default_factory=dict)  # resolved SlamConfig as plain data
    intrinsics: Intrinsics | None = None
    keyframes: list[tuple[int, np.ndarray]] = field(default_factory=list)  # (frame index, c2w [4, 4])
    trajectory: list[tuple[int, int, np.ndarray]] = field(default_factory=list)  # (input frame index, stamp_ns, c2w)
    seen_labels: list[int] = field(default_factory=list)  # class ids observed while mapping (decoding candidates)
    scene_radius: float | None = None  # m, for pruning huge Gaussians when mapping resumes
    locked_labels: list[int] = field(default_factory=list)  # classes locked by edits (see slam.edits)
    keyframe_images: list[CompactFrame] = field(default_factory=list)  # recent keyframes, oldest first
    frames_processed: int | None = None  # the Slam's frame counter (None: len(trajectory))


def _intrinsics_dict(k: Intrinsics | None) -> dict[str, float] | None:
    if k is None:
        return None
    return {"fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy, "width": k.width, "height": k.height}


def _keyframe_dict(kf: CompactFrame) -> dict[str, Any]:
    return {
        "index": kf.index,
        "stamp_ns": kf.stamp_ns,
        "rgb": torch.from_numpy(kf.rgb),
        "depth": torch.from_numpy(kf.depth),
        "labels": None if kf.labels is None else torch.from_numpy(kf.labels),
        "w2c": torch.from_numpy(kf.w2c),
    }


def _keyframe_from_dict(d: dict[str, Any], k: Intrinsics | None) -> CompactFrame:
    if k is None:
        raise ValueError("keyframe images need the map's intrinsics")
    rgb, depth, labels = d["rgb"].numpy(), d["depth"].numpy(), None if d["labels"] is None else d["labels"].numpy()
    if (
        rgb.shape != (k.height, k.width, 3)
        or depth.shape != k.shape
        or (labels is not None and labels.shape != k.shape)
    ):
        raise ValueError(f"keyframe {d['index']} images do not match the intrinsics ({k.width}x{k.height})")
    if rgb.dtype != np.uint8 or depth.dtype != np.uint16:
        raise ValueError(f"keyframe {d['index']} images must be uint8 colour and uint16 depth")
    if labels is not None and labels.dtype not in (np.uint8, np.uint16, np.int32):
        raise ValueError(f"keyframe {d['index']} labels must be uint8, uint16 or int32, got {labels.dtype}")
    labels = None if labels is None else compact_labels(labels)  # files before the store kept int32
    return CompactFrame(int(d["index"]), int(d["stamp_ns"]), k, rgb, depth, labels, d["w2c"].numpy())


def _host(pose: np.ndarray) -> torch.Tensor:  # [4, 4] float64 on the CPU (files hold host tensors)
    return torch.as_tensor(pose, dtype=torch.float64, device="cpu")


_CHUNK = 2**20  # bytes written in one part of a write in turns


def save_map(path: str | Path, m: MapFile, turn: Callable[[], AbstractContextManager[None]] | None = None) -> int:
    """Write ``m`` to ``path`` atomically (a crash leaves any previous file intact); returns its size (bytes).

    ``turn()``: a context in which each part of the work runs (the serialising, then each MiB
    written), so that a background writer can take turns with tracking for the CPU.
    """
    part = turn or contextlib.nullcontext
    payload = {
        "format": FORMAT,
        "version": VERSION,
        "gaussians": m.gaussians.state_dict(),
        "label_table": m.label_table.to_dict(),
        "config": m.config,
        "intrinsics": _intrinsics_dict(m.intrinsics),
        "keyframes": [[int(i), _host(p)] for i, p in m.keyframes],
        "trajectory": [[int(i), int(s), _host(p)] for i, s, p in m.trajectory],
        "seen_labels": [int(i) for i in m.seen_labels],
        "scene_radius": m.scene_radius,
        "locked_labels": [int(i) for i in m.locked_labels],
        "keyframe_images": [_keyframe_dict(kf) for kf in m.keyframe_images],
        "frames_processed": m.frames_processed,
    }
    buffer = io.BytesIO()  # torch.save turns a failing file write (disk full) into a RuntimeError: write it ourselves
    with part():
        torch.save(payload, buffer)
    data = buffer.getbuffer()

    def write(f: BinaryIO) -> None:
        for start in range(0, data.nbytes, _CHUNK):
            with part():
                f.write(data[start : start + _CHUNK])

    atomic_write(path, write)
    return data.nbytes


def load_map(path: str | Path, device: torch.device | str = "cpu") -> MapFile:
    """Read and validate a native map; every problem raises :class:`MapFileError` naming it."""
    path = Path(path)
    if not path.is_file():
        raise MapFileError(f"map file {path} does not exist")
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except (RuntimeError, EOFError, OSError, pickle.UnpicklingError, zipfile.BadZipFile, ValueError) as err:
        detail = str(err).splitlines()[0][:200] if str(err) else ""  # torch's messages run to paragraphs
        raise MapFileError(f"map file {path} is truncated or not a map ({type(err).__name__}: {detail})") from err
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise MapFileError(f"{path} is not an SGS-SLAM map (format tag missing)")
    if data.get("version") != VERSION:
        raise MapFileError(f"{path}: map version {data.get('version')!r} is not supported (expected {VERSION})")
    missing = [k for k in _REQUIRED if k not in data]
    if missing:
        raise MapFileError(f"{path}: missing fields {missing}")
    try:
        gaussians = GaussianMap.from_state_dict(data["gaussians"], device)
        table = LabelTable.from_dict(data["label_table"])
        k = Intrinsics(**data["intrinsics"]) if data["intrinsics"] else None
        keyframes = [(int(i), p.numpy()) for i, p in data["keyframes"]]
        trajectory = [(int(i), int(s), p.numpy()) for i, s, p in data["trajectory"]]
        seen = [int(i) for i in data.get("seen_labels", [])]
        locked = [int(i) for i in data.get("locked_labels", [])]
        images = [_keyframe_from_dict(d, k) for d in data.get("keyframe_images", [])]
        processed = data.get("frames_processed")
        processed = None if processed is None else as_int(processed, "frames_processed", MapFileError, 0)
        radius = data.get("scene_radius")
        radius = None if radius is None else as_float(radius, "scene_radius", MapFileError, 0.0, lo_open=True)
    except (ShapeError, LabelError, TypeError, ValueError, AttributeError, KeyError, IndexError) as err:
        raise MapFileError(f"{path}: {type(err).__name__}: {err}") from err
    except MapFileError as err:
        raise MapFileError(f"{path}: {err}") from err
    if not isinstance(data["config"], dict):
        raise MapFileError(f"{path}: config must be a mapping, got {type(data['config']).__name__}")
    for _, pose in [*keyframes, *((i, p) for i, _, p in trajectory)]:
        if pose.shape != (4, 4):
            raise MapFileError(f"{path}: poses must be 4x4, found {pose.shape}")
    return MapFile(
        gaussians, table, dict(data["config"]), k, keyframes, trajectory, seen, radius, locked, images, processed
    )
