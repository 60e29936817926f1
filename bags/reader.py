"""Frames from an MCAP bag (ours or recorded elsewhere), as a core ``Dataset``.

One indexing walk (``McapIndex``) reads every message's header stamp (the first bytes of its CDR
payload, without decoding images), synchronises colour, depth and labels with the same
approximate-time synchroniser the ROS nodes use, and attaches the camera_info and ground-truth pose
of each frame. Frames are then decoded on demand, one read per message.
"""

from __future__ import annotations

import bisect
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from bags.cdr_image import CdrImage, decode_image
from bags.errors import BagError
from bags.layout import BagTopics
from bags.mcap_index import McapIndex, MessageRef
from msg_adapters import (
    AdapterError,
    ApproximateSync,
    camera_info_to_intrinsics,
    depth_from_image,
    labels_from_image,
    pose_to_c2w,
    rgb_from_image,
)
from sgs_slam_core.datasets.base import DatasetOptions, check_frame_size, resize_frame
from sgs_slam_core.errors import SgsSlamError
from sgs_slam_core.fileio import read_text
from sgs_slam_core.frame import Frame
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.labels import LabelError, LabelTable
from sgs_slam_core.validate import as_float

__all__ = [
    "BagDataset",
    "bag_file",
    "open_bag",
    "open_index",
    "read_custom_data",
    "read_depth_units",
    "read_label_table",
    "read_metadata",
]

_YAML_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
DEFAULT_DEPTH_UNITS_PER_M = 1000.0
DEPTH_UNITS_KEYS = ("depth_units_per_metre", "depth_scale")  # libyaml: 20x faster on a large label table
_IMAGE = "sensor_msgs/msg/Image"


def bag_file(path: Path) -> Path:
    """The MCAP file of a bag folder (or the file itself)."""
    if path.is_file():
        return path
    files = sorted(path.glob("*.mcap"))
    if not files:
        raise BagError(f"{path}: no .mcap file in the bag folder")
    return files[0]


def read_metadata(path: Path) -> dict[str, Any]:
    """``rosbag2_bagfile_information`` of a rosbag2 folder's metadata.yaml (empty for a bare .mcap)."""
    meta = (path if path.is_dir() else path.parent) / "metadata.yaml"
    if not meta.is_file():
        return {}
    try:
        data = yaml.load(read_text(meta, "bag metadata", BagError), Loader=_YAML_LOADER)
    except yaml.YAMLError as err:
        raise BagError(f"{meta} is not valid rosbag2 metadata: {err}") from err
    if not isinstance(data, dict):
        raise BagError(f"{meta} is not valid rosbag2 metadata: expected a mapping")
    info = data.get("rosbag2_bagfile_information", {})
    if not isinstance(info, dict):
        raise BagError(f"{meta} is not valid rosbag2 metadata: rosbag2_bagfile_information is not a mapping")
    return info


def read_custom_data(path: Path) -> dict[str, str]:
    """``custom_data`` of a rosbag2 folder's metadata.yaml (empty for a bare .mcap); unknown keys are kept."""
    custom = read_metadata(path).get("custom_data") or {}
    if not isinstance(custom, dict):
        raise BagError(f"{path}: custom_data in metadata.yaml must be a mapping, got {type(custom).__name__}")
    return {str(k): str(v) for k, v in custom.items()}


def read_label_table(path: Path, custom: dict[str, str]) -> LabelTable:
    """The label table stored in a bag's metadata (an empty table when there is none)."""
    if "label_table" not in custom:
        return LabelTable()
    try:
        return LabelTable.from_dict(json.loads(custom["label_table"]))
    except (json.JSONDecodeError, LabelError) as err:
        raise BagError(f"{path}: metadata custom_data label_table: {err}") from err


def read_depth_units(path: Path, custom: dict[str, str]) -> float:
    """16-bit depth units per metre from the bag's metadata (1000 when absent).

    The key is ``depth_units_per_metre``; ``depth_scale`` (the nodes' parameter name) is read too.
    """
    values = {
        k: as_float(custom[k], f"{path}: metadata custom_data {k}", BagError, 0.0, lo_open=True)
        for k in DEPTH_UNITS_KEYS
        if k in custom
    }
    if len(set(values.values())) > 1:
        raise BagError(f"{path}: metadata custom_data disagree on the depth units: {values}")
    return next(iter(values.values()), DEFAULT_DEPTH_UNITS_PER_M)


def open_index(file: Path) -> McapIndex:
    """Index an MCAP file; a truncated file (a recording that was never closed) is refused."""
    try:
        index = McapIndex(file)
    except OSError as err:
        raise BagError(f"{file}: cannot read ({err})") from err
    if index.truncated_at is not None:
        index.close()
        raise BagError(
            f"{file} is corrupt or truncated: no complete record at byte {index.truncated_at} "
            "(`mcap recover` rewrites what is intact)"
        )
    return index


@dataclass
class _FrameIndex:
    stamp_ns: int
    messages: dict[str, MessageRef]  # topic -> the message to decode


class BagDataset:
    """A bag's synchronised frames; satisfies the core ``Dataset`` protocol."""

    name = "mcap"

    def __init__(
        self,
        path: str | Path,
        options: DatasetOptions | None = None,
        topics: BagTopics = BagTopics(),  # noqa: B008 - immutable default
        slop_ns: int = 20_000_000,
        queue_size: int = 10,
        depth_units_per_metre: float | None = None,
    ) -> None:
        self.path = Path(path)
        self.file = bag_file(self.path)
        self._slop_ns, self._queue_size = slop_ns, queue_size
        self.topics = topics
        self.options = options or DatasetOptions()
        custom = read_custom_data(self.path)
        self.dataset_name = custom.get("dataset", "")
        self.depth_scale = depth_units_per_metre or read_depth_units(self.path, custom)
        self._table = read_label_table(self.path, custom)
        self._mcap = open_index(self.file)
        frames, infos, poses = self._index()
        self._infos, self._poses = infos, poses
        self._frames = [frames[i] for i in self.options.select(len(frames))]
        if not self._frames:
            raise BagError(f"{self.file}: no synchronised {topics.color} / {topics.depth} frames")
        native = self._intrinsics_at(self._frames[0].stamp_ns)
        self._native = native
        self._intrinsics = native if self.options.downscale == 1.0 else native.scaled(1.0 / self.options.downscale)
        check_frame_size(self._intrinsics, self.options)

    # ------------------------------------------------------------------ indexing
    def _index(self) -> tuple[list[_FrameIndex], list[tuple[int, MessageRef]], dict[int, MessageRef]]:
        t = self.topics
        wanted = (t.color, t.depth, t.semantic, t.camera_info, t.pose)
        topic_of = {cid: topic for topic, ids in self._mcap.topic_channels(wanted).items() for cid in ids}
        for cid, topic in topic_of.items():
            schema = self._mcap.channels[cid].schema
            if topic in (t.color, t.depth, t.semantic) and (schema is None or schema.name != _IMAGE):
                raise BagError(f"{self.file}: {topic} carries {schema.name if schema else '?'}, expected {_IMAGE}")
        stamps: dict[str, list[tuple[int, MessageRef]]] = {k: [] for k in wanted}
        for ref in sorted(self._mcap.messages, key=lambda m: m.log_time):  # stable: file order breaks ties
            topic = topic_of.get(ref.channel_id)
            if topic is None:
                continue
            if ref.stamp_ns is None:
                raise BagError(f"{self.file}: message on {topic} at {ref.log_time} ns has no CDR header stamp")
            stamps[topic].append((ref.stamp_ns, ref))
        for needed in (t.color, t.depth, t.camera_info):
            if not stamps[needed]:
                raise BagError(
                    f"{self.file}: no messages on {needed} (set the topic names for bags recorded elsewhere)"
                )
        self.has_labels = bool(stamps[t.semantic])
        streams = [t.color, t.depth, *([t.semantic] if self.has_labels else [])]
        # Replay the recording in log-time order through the nodes' synchroniser; items are message refs.
        sync = ApproximateSync(len(streams), self._queue_size, self._slop_ns)
        events = sorted(
            ((ref.log_time, i, stamp, ref) for i, s in enumerate(streams) for stamp, ref in stamps[s]),
            key=lambda e: e[:3],
        )
        frames = []
        for _, i, stamp, ref in events:
            match = sync.push(i, stamp, ref)
            if match is not None:
                frames.append(_FrameIndex(match[0], dict(zip(streams, match[1], strict=True))))
        infos = sorted(stamps[t.camera_info], key=lambda e: (e[0], e[1].log_time))
        poses = dict(stamps[t.pose])
        return frames, infos, poses

    def _intrinsics_at(self, stamp_ns: int) -> Intrinsics:
        i = bisect.bisect_right([s for s, _ in self._infos], stamp_ns) - 1
        msg = self._mcap.decode(self._infos[max(i, 0)][1])
        try:
            k, _ = camera_info_to_intrinsics(msg)
        except AdapterError as err:
            raise BagError(f"{self.file}: bad camera_info: {err}") from err
        return k

    def _image(self, ref: MessageRef) -> CdrImage:
        try:
            return decode_image(self._mcap.payload(ref))
        except ValueError as err:
            raise BagError(f"{self.file}: image at {ref.log_time} ns does not decode ({err})") from err

    # ------------------------------------------------------------------ Dataset protocol
    @property
    def intrinsics(self) -> Intrinsics:
        """Intrinsics after downscaling."""
        return self._intrinsics

    @property
    def label_table(self) -> LabelTable:
        """From the bag's metadata (unknown ids get palette colours)."""
        return self._table

    @property
    def has_ground_truth(self) -> bool:
        """True when the bag carries ground-truth poses for its frames."""
        return any(f.stamp_ns in self._poses for f in self._frames)

    @property
    def stamps_ns(self) -> list[int]:
        """Header stamps of the kept frames."""
        return [f.stamp_ns for f in self._frames]

    def ground_truth(self, index: int) -> np.ndarray | None:
        """The recorded pose of kept frame ``index`` as c2w [4, 4], or None (no image is decoded)."""
        idx = self._frames[index]
        pose = self._poses.get(idx.stamp_ns)
        try:
            gt = pose_to_c2w(self._mcap.decode(pose)) if pose is not None else None
        except AdapterError as err:
            raise BagError(f"{self.file}, pose at {idx.stamp_ns} ns: {err}") from err
        if gt is not None and not np.isfinite(gt).all():  # as Frame refuses it
            raise BagError(f"{self.file}, pose at {idx.stamp_ns} ns is not finite")
        return gt

    def __len__(self) -> int:
        return len(self._frames)

    def __getitem__(self, index: int) -> Frame:
        if not -len(self) <= index < len(self):
            raise IndexError(f"frame {index} out of range for {len(self)} frames")
        idx = self._frames[index % len(self)]
        t = self.topics
        try:
            msgs = idx.messages
            rgb = rgb_from_image(self._image(msgs[t.color]))
            depth = depth_from_image(self._image(msgs[t.depth]), self.depth_scale)
            labels = labels_from_image(self._image(msgs[t.semantic])) if self.has_labels else None
            pose = self._poses.get(idx.stamp_ns)
            gt = pose_to_c2w(self._mcap.decode(pose)) if pose is not None else None
        except AdapterError as err:
            raise BagError(f"{self.file}, frame at {idx.stamp_ns} ns: {err}") from err
        k = self._intrinsics
        rgb, depth, labels = resize_frame(rgb, depth, labels, k.width, k.height)
        try:
            return Frame(rgb, depth, k, labels, idx.stamp_ns, gt, index % len(self))
        except SgsSlamError as err:
            raise BagError(f"{self.file}, frame at {idx.stamp_ns} ns: {err}") from err

    def close(self) -> None:
        """Close the file."""
        self._mcap.close()


def open_bag(path: str | Path, options: DatasetOptions | None = None, topics: BagTopics | None = None) -> BagDataset:
    """Open a bag folder or .mcap file."""
    path = Path(path)
    if not path.exists():
        raise BagError(f"{path} does not exist")
    return BagDataset(path, options, topics or BagTopics())
