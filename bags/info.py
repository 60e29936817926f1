"""What a bag holds: topics, message counts, duration, image encodings, label table."""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from pathlib import Path

from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from bags.cdr_image import decode_image
from bags.errors import BagError
from bags.mcap_index import McapIndex
from bags.reader import bag_file, read_custom_data, read_label_table

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
    truncated_at: int | None = None  # byte offset of the first incomplete record (no summary section)

    @property
    def duration_s(self) -> float:
        """Time between the first and last message (s)."""
        return (self.end_ns - self.start_ns) / 1e9

    def format(self) -> str:
        """Human-readable table."""
        lines = [f"bag:      {self.path}", f"duration: {self.duration_s:.3f} s ({self.start_ns} .. {self.end_ns} ns)"]
        if self.truncated_at is not None:
            lines.append(
                f"WARNING:  truncated at byte {self.truncated_at}; counts are of the complete records before it"
            )
        if self.custom.get("dataset"):
            lines.append(f"dataset:  {self.custom['dataset']}")
        width = max((len(t.name) for t in self.topics), default=0)
        lines.append("topics:")
        for t in self.topics:
            extra = f"  {t.encoding} {t.size}" if t.encoding else ""
            lines.append(f"  {t.name.ljust(width)}  {t.count:6d} x {t.msgtype}{extra}")
        if "label_table" in self.custom:
            try:
                table = read_label_table(self.path, self.custom)
            except BagError as err:
                lines.append(f"labels:   unreadable ({err})")
            else:
                names = [f"{c.id}:{c.name}" for c in table]
                more = f" ... ({len(names) - 40} more)" if len(names) > 40 else ""
                count = f"{len(names)} class{'es' * (len(names) != 1)}"
                lines.append(f"labels:   table '{table.name}', {count}: {' '.join(names[:40])}{more}")
        return "\n".join(lines)


def bag_info(path: str | Path) -> BagInfo:
    """Read the summary (and the first message of every image topic for its encoding).

    A bag without a readable summary (a recording that was never closed) is described from its
    complete records instead, with ``truncated_at`` set.
    """
    path = Path(path)
    if not path.exists():
        raise BagError(f"{path} does not exist")
    file = bag_file(path)
    try:
        with file.open("rb") as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            try:
                summary = reader.get_summary()
            except _READ_ERRORS:
                summary = None  # no readable footer: a recording that was not closed
            if summary is None or summary.statistics is None:
                return _info_by_walking(path, file)
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


def _info_by_walking(path: Path, file: Path) -> BagInfo:
    """Counts and encodings from the records themselves (a bag without a summary, e.g. truncated)."""
    index = McapIndex(file)
    try:
        counts: dict[int, int] = {}
        first: dict[int, int] = {}
        for i, ref in enumerate(index.messages):
            counts[ref.channel_id] = counts.get(ref.channel_id, 0) + 1
            first.setdefault(ref.channel_id, i)
        topics = []
        for cid, ch in sorted(index.channels.items(), key=lambda kv: kv[1].topic):
            info = TopicInfo(ch.topic, ch.schema.name if ch.schema else "?", counts.get(cid, 0))
            if info.msgtype == "sensor_msgs/msg/Image" and info.count:
                try:
                    img = decode_image(index.payload(index.messages[first[cid]]))
                    info.encoding, info.size = img.encoding, f"{img.width}x{img.height}"
                except ValueError:
                    info.encoding = "?"
            topics.append(info)
        times = [m.log_time for m in index.messages] or [0]
        return BagInfo(path, min(times), max(times), topics, read_custom_data(path), index.truncated_at)
    finally:
        index.close()
