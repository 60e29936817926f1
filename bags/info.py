"""What a bag holds: topics, message counts, duration, image encodings, label table."""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass, field
from pathlib import Path

from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from bags.errors import BagError
from bags.reader import bag_file, read_custom_data

__all__ = ["BagInfo", "TopicInfo", "bag_info"]

_READ_ERRORS = (McapError, EOFError, OSError, struct.error, ValueError, RuntimeError)  # what the mcap reader raises


@dataclass
class TopicInfo:
    """One topic of a bag."""

    name: str
    msgtype: str
    count: int
    encoding: str = ""  # images only
    size: str = ""  # images: WxH


@dataclass
class BagInfo:
    """Summary of a bag."""

    path: Path
    start_ns: int
    end_ns: int
    topics: list[TopicInfo]
    custom: dict[str, str] = field(default_factory=dict)

    @property
    def duration_s(self) -> float:
        """Time between the first and last message (s)."""
        return (self.end_ns - self.start_ns) / 1e9

    def format(self) -> str:
        """Human-readable table."""
        lines = [f"bag:      {self.path}", f"duration: {self.duration_s:.3f} s ({self.start_ns} .. {self.end_ns} ns)"]
        if self.custom.get("dataset"):
            lines.append(f"dataset:  {self.custom['dataset']}")
        width = max(len(t.name) for t in self.topics)
        lines.append("topics:")
        for t in self.topics:
            extra = f"  {t.encoding} {t.size}" if t.encoding else ""
            lines.append(f"  {t.name.ljust(width)}  {t.count:6d} x {t.msgtype}{extra}")
        if "label_table" in self.custom:
            table = json.loads(self.custom["label_table"])
            names = [f"{c['id']}:{c['name']}" for c in table.get("classes", []) if c["id"]]
            lines.append(f"labels:   {table.get('name', '')} ({len(names)} classes) {' '.join(names[:40])}")
        return "\n".join(lines)


def bag_info(path: str | Path) -> BagInfo:
    """Read the summary (and the first message of every image topic for its encoding)."""
    path = Path(path)
    if not path.exists():
        raise BagError(f"{path} does not exist")
    file = bag_file(path)
    try:
        with file.open("rb") as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            summary = reader.get_summary()
            if summary is None or summary.statistics is None:
                raise BagError(f"{file} has no summary section (truncated, or written without one)")
            stats = summary.statistics
            topics = []
            for cid, channel in sorted(summary.channels.items(), key=lambda kv: kv[1].topic):
                schema = summary.schemas.get(channel.schema_id)
                info = TopicInfo(
                    channel.topic, schema.name if schema else "?", stats.channel_message_counts.get(cid, 0)
                )
                if info.msgtype == "sensor_msgs/msg/Image" and info.count:
                    for _, _, _, msg in reader.iter_decoded_messages(topics=[channel.topic]):
                        info.encoding, info.size = msg.encoding, f"{msg.width}x{msg.height}"
                        break
                topics.append(info)
    except _READ_ERRORS as err:
        raise BagError(f"{file} is corrupt or truncated ({type(err).__name__}: {err})") from err
    return BagInfo(path, stats.message_start_time, stats.message_end_time, topics, read_custom_data(path))
