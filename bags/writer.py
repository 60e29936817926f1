"""Convert any dataset the core reads into a rosbag2 (version 9, MCAP storage) bag.

Topics: colour (rgb8), camera_info, depth (16UC1 mm, registered to colour), semantic class ids
(16UC1, when the dataset has labels), the ground-truth PoseStamped in ``map`` (when present) and
``/clock``; one stamp per frame shared by every topic, so ExactTime synchronisation works on
replay. The label table, dataset name, depth units and config preset go into the bag's custom
metadata.
Compression is zstd at the storage (chunk) level, so plain MCAP readers still work.
"""

from __future__ import annotations

import json
import os
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rosbags.interfaces import Connection
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from bags import rosbags_messages as rm
from bags.errors import BagError
from bags.layout import BagTopics
from bags.preset import preset_metadata
from msg_adapters import c2w_to_pose, camera_info_fields, image_fields
from msg_adapters.stamps import ns_to_stamp
from sgs_slam_core.datasets.base import Dataset
from sgs_slam_core.frame import Frame
from sgs_slam_core.frame_ids import CAMERA_FRAME, MAP_FRAME

__all__ = ["DEPTH_UNITS_PER_M", "ConvertSummary", "convert"]

DEPTH_UNITS_PER_M = 1000.0


@dataclass(frozen=True)
class ConvertSummary:
    """What was written."""

    path: Path
    frames: int
    bytes: int
    topics: tuple[str, ...]


def _frames_ahead(dataset: Dataset, n: int, ahead: int = 6) -> Iterator[Frame]:
    """Frames 0..n-1 in order, decoded ``ahead`` frames in advance on worker threads.

    Image decoding releases the GIL, so PNG/JPEG reading overlaps the bag writing.
    """
    workers = max(1, min(4, os.cpu_count() or 1))
    with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="bag-convert") as pool:
        pending: deque[Future[Frame]] = deque(pool.submit(dataset.__getitem__, i) for i in range(min(ahead, n)))
        for i in range(n):
            frame = pending.popleft().result()
            if i + ahead < n:
                pending.append(pool.submit(dataset.__getitem__, i + ahead))
            yield frame


def convert(
    dataset: Dataset,
    out: str | Path,
    compress: bool = True,
    max_frames: int | None = None,
    dataset_name: str = "",
    topics: BagTopics = BagTopics(),  # noqa: B008 - immutable default
    progress: Callable[[int, int], None] | None = None,
    preset: str | None = None,
) -> ConvertSummary:
    """Write ``dataset`` (its first ``max_frames`` frames) to the bag folder ``out``; never overwrites.

    ``preset`` (the config preset of the dataset folder) is stored in the metadata, so a run on the
    bag uses the same preset as a run on the folder.
    """
    out = Path(out)
    custom = preset_metadata(preset) if preset is not None else {}
    if out.exists():
        raise BagError(f"{out} exists; refusing to overwrite")
    n = len(dataset) if max_frames is None else min(max_frames, len(dataset))
    if n == 0:
        raise BagError("the dataset has no frames to convert")
    ts = get_typestore(Stores.ROS2_JAZZY)
    writer = Writer(out, version=9, storage_plugin=StoragePlugin.MCAP)
    if compress:
        writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    with writer:
        conn = _connections(writer, topics, dataset, ts)
        writer.set_custom_data("dataset", dataset_name or getattr(dataset, "name", "dataset"))
        writer.set_custom_data("label_table", json.dumps(dataset.label_table.to_dict(), separators=(",", ":")))
        writer.set_custom_data("depth_units_per_metre", str(DEPTH_UNITS_PER_M))
        writer.set_custom_data("frames", str(n))
        for key, value in custom.items():
            writer.set_custom_data(key, value)
        for i, frame in enumerate(_frames_ahead(dataset, n)):
            _write_frame(writer, conn, ts, frame, i)
            if progress:
                progress(i + 1, n)
    written = tuple(c.topic for c in conn.values())
    size = sum(p.stat().st_size for p in out.iterdir())
    return ConvertSummary(out, n, size, written)


def _connections(writer: Writer, topics: BagTopics, dataset: Dataset, ts: Typestore) -> dict[str, Connection]:
    """One connection per stream the dataset has (labels and ground truth only when it has them)."""
    streams = {
        "color": (topics.color, "sensor_msgs/msg/Image"),
        "info": (topics.camera_info, "sensor_msgs/msg/CameraInfo"),
        "depth": (topics.depth, "sensor_msgs/msg/Image"),
        "clock": (topics.clock, "rosgraph_msgs/msg/Clock"),
    }
    if dataset.has_labels:
        streams["semantic"] = (topics.semantic, "sensor_msgs/msg/Image")
    if dataset.has_ground_truth:
        streams["pose"] = (topics.pose, "geometry_msgs/msg/PoseStamped")
    return {key: writer.add_connection(topic, kind, typestore=ts) for key, (topic, kind) in streams.items()}


def _write_frame(writer: Writer, conn: dict[str, Connection], ts: Typestore, frame: Frame, i: int) -> None:
    """Frame ``i``'s messages, all stamped with its time stamp."""
    stamp = frame.stamp_ns

    def put(key: str, msg: object) -> None:
        writer.write(conn[key], stamp, ts.serialize_cdr(msg, msg.__msgtype__))  # type: ignore[attr-defined]

    put("clock", rm.clock(ts, *ns_to_stamp(stamp)))
    put("info", rm.camera_info(ts, camera_info_fields(frame.intrinsics, stamp, CAMERA_FRAME)))
    put("color", rm.image(ts, image_fields(frame.rgb, "rgb8", stamp, CAMERA_FRAME)))
    units = np.round(frame.depth * DEPTH_UNITS_PER_M)
    depth = np.where(units <= 65535, units, 0).astype(np.uint16)
    put("depth", rm.image(ts, image_fields(depth, "16UC1", stamp, CAMERA_FRAME)))
    if "semantic" in conn and frame.labels is not None:
        if frame.labels.max(initial=0) > 65535:
            raise BagError(f"frame {i}: class id {frame.labels.max()} does not fit a 16UC1 label image")
        put("semantic", rm.image(ts, image_fields(frame.labels.astype(np.uint16), "16UC1", stamp, CAMERA_FRAME)))
    if "pose" in conn and frame.gt_c2w is not None:
        put("pose", rm.pose_stamped(ts, c2w_to_pose(frame.gt_c2w, stamp, MAP_FRAME)))
