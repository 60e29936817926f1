"""Frames from an MCAP bag (ours or recorded elsewhere), as a core ``Dataset``.

One indexing pass reads every message's header stamp (the first bytes of its CDR payload, without
decoding images), synchronises colour, depth and labels with the same approximate-time
synchroniser the ROS nodes use, and attaches the camera_info and ground-truth pose of each frame.
Frames are then decoded on demand through the MCAP chunk index.
"""

from __future__ import annotations

import bisect
import json
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import yaml
from mcap.exceptions import McapError
from mcap.reader import McapReader, make_reader
from mcap_ros2.decoder import DecoderFactory

from bags.errors import BagError
from bags.layout import BagTopics
from msg_adapters import (
    AdapterError,
    ApproximateSync,
    camera_info_to_intrinsics,
    depth_from_image,
    labels_from_image,
    pose_to_c2w,
    rgb_from_image,
)
from sgs_slam_core.datasets.base import DatasetOptions, resize_frame
from sgs_slam_core.errors import SgsSlamError
from sgs_slam_core.frame import Frame
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.labels import LabelError, LabelTable

__all__ = ["BagDataset", "bag_file", "open_bag", "read_custom_data"]

_READ_ERRORS = (McapError, EOFError, OSError, struct.error, ValueError, RuntimeError)


def bag_file(path: Path) -> Path:
    """The MCAP file of a bag folder (or the file itself)."""
    if path.is_file():
        return path
    files = sorted(path.glob("*.mcap"))
    if not files:
        raise BagError(f"{path}: no .mcap file in the bag folder")
    return files[0]


def read_custom_data(path: Path) -> dict[str, str]:
    """``custom_data`` of a rosbag2 folder's metadata.yaml (empty for a bare .mcap)."""
    meta = (path if path.is_dir() else path.parent) / "metadata.yaml"
    if not meta.is_file():
        return {}
    try:
        info = yaml.safe_load(meta.read_text()).get("rosbag2_bagfile_information", {})
    except (yaml.YAMLError, AttributeError) as err:
        raise BagError(f"{meta} is not valid rosbag2 metadata: {err}") from err
    return {str(k): str(v) for k, v in (info.get("custom_data") or {}).items()}


def _header_stamp(data: bytes) -> int:
    """Header stamp (ns) of a CDR message whose first field is a std_msgs/Header."""
    if len(data) < 12:
        raise ValueError("message shorter than a header")
    little = data[1] == 1  # encapsulation: 0x00 0x01 = CDR little endian
    sec, nanosec = struct.unpack("<iI" if little else ">iI", data[4:12])
    return sec * 1_000_000_000 + nanosec


@dataclass
class _FrameIndex:
    stamp_ns: int
    log_times: dict[str, int]  # topic -> log time of the message to decode


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
        self.depth_scale = depth_units_per_metre or float(custom.get("depth_units_per_metre", 1000.0))
        try:
            self._table = (
                LabelTable.from_dict(json.loads(custom["label_table"])) if "label_table" in custom else LabelTable()
            )
        except (json.JSONDecodeError, LabelError) as err:
            raise BagError(f"{self.path}: bad label table in metadata: {err}") from err
        self._stream: BinaryIO = self.file.open("rb")
        try:
            self._reader: McapReader = make_reader(self._stream, decoder_factories=[DecoderFactory()])
        except _READ_ERRORS as err:
            self._stream.close()
            raise BagError(f"{self.file} is corrupt or truncated ({type(err).__name__}: {err})") from err
        frames, infos, poses = self._index()
        self._infos, self._poses = infos, poses
        self._frames = [frames[i] for i in self.options.select(len(frames))]
        if not self._frames:
            raise BagError(f"{self.file}: no synchronised {topics.color} / {topics.depth} frames")
        native = self._intrinsics_at(self._frames[0].stamp_ns)
        self._native = native
        self._intrinsics = native if self.options.downscale == 1.0 else native.scaled(1.0 / self.options.downscale)

    # ------------------------------------------------------------------ indexing
    def _index(self) -> tuple[list[_FrameIndex], list[tuple[int, int]], dict[int, int]]:
        t = self.topics
        stamps: dict[str, list[tuple[int, int]]] = {
            k: [] for k in (t.color, t.depth, t.semantic, t.camera_info, t.pose)
        }
        try:
            for _, channel, message in self._reader.iter_messages(topics=list(stamps), log_time_order=True):
                stamps[channel.topic].append((_header_stamp(message.data), message.log_time))
        except _READ_ERRORS as err:
            raise BagError(f"{self.file} is corrupt or truncated ({type(err).__name__}: {err})") from err
        for needed in (t.color, t.depth, t.camera_info):
            if not stamps[needed]:
                raise BagError(
                    f"{self.file}: no messages on {needed} (set the topic names for bags recorded elsewhere)"
                )
        self.has_labels = bool(stamps[t.semantic])
        streams = [t.color, t.depth, *([t.semantic] if self.has_labels else [])]
        # Replay the recording in log-time order through the nodes' synchroniser; items are log times.
        sync = ApproximateSync(len(streams), self._queue_size, self._slop_ns)
        events = sorted((lt, i, stamp) for i, s in enumerate(streams) for stamp, lt in stamps[s])
        frames = []
        for log_time, i, stamp in events:
            match = sync.push(i, stamp, log_time)
            if match is not None:
                frames.append(_FrameIndex(match[0], dict(zip(streams, match[1], strict=True))))
        infos = sorted(stamps[t.camera_info])
        poses = dict(stamps[t.pose])
        return frames, infos, poses

    def _intrinsics_at(self, stamp_ns: int) -> Intrinsics:
        msg = self._decode(self.topics.camera_info, self._info_log_time(stamp_ns))
        try:
            k, _ = camera_info_to_intrinsics(msg)
        except AdapterError as err:
            raise BagError(f"{self.file}: bad camera_info: {err}") from err
        return k

    def _info_log_time(self, stamp_ns: int) -> int:
        i = bisect.bisect_right(self._infos, (stamp_ns, float("inf"))) - 1
        return self._infos[max(i, 0)][1]

    def _decode(self, topic: str, log_time: int) -> Any:
        try:
            for _, channel, _, decoded in self._reader.iter_decoded_messages(
                topics=[topic], starting_at=log_time, ending_at=log_time
            ):
                if channel.topic == topic:
                    return decoded
        except _READ_ERRORS as err:
            raise BagError(f"{self.file} is corrupt or truncated ({type(err).__name__}: {err})") from err
        raise BagError(f"{self.file}: message on {topic} at {log_time} ns not found")

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

    def __len__(self) -> int:
        return len(self._frames)

    def __getitem__(self, index: int) -> Frame:
        if not -len(self) <= index < len(self):
            raise IndexError(f"frame {index} out of range for {len(self)} frames")
        idx = self._frames[index % len(self)]
        t = self.topics
        try:
            rgb = rgb_from_image(self._decode(t.color, idx.log_times[t.color]))
            depth = depth_from_image(self._decode(t.depth, idx.log_times[t.depth]), self.depth_scale)
            labels = labels_from_image(self._decode(t.semantic, idx.log_times[t.semantic])) if self.has_labels else None
            gt = pose_to_c2w(self._decode(t.pose, self._poses[idx.stamp_ns])) if idx.stamp_ns in self._poses else None
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
        self._stream.close()


def open_bag(path: str | Path, options: DatasetOptions | None = None, topics: BagTopics | None = None) -> BagDataset:
    """Open a bag folder or .mcap file."""
    path = Path(path)
    if not path.exists():
        raise BagError(f"{path} does not exist")
    return BagDataset(path, options, topics or BagTopics())
