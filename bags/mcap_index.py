"""Random access to the messages of an MCAP file: one indexing walk, then one read per message.

The ``mcap`` library's seeking reader re-reads (and re-decompresses) whole chunks for every time
query and copies every record through ``BytesIO``; reading a 640x480 RGB-D frame that way costs
~10 ms. Here the file's records are walked once (MCAP spec, https://mcap.dev/spec): schemas,
channels, and for every message its log time, header stamp and position. A message in an
uncompressed chunk is then one ``pread`` of exactly its payload; compressed chunks (zstd, lz4) are
decompressed once, checked against their CRC, and the last few kept. The walk needs no summary
section, so bags without one (``ros2 bag record`` killed before it closed the file) index up to the
first incomplete record, which is reported as ``truncated_at``.
"""

from __future__ import annotations

import os
import struct
import threading
import zlib
from collections import OrderedDict
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import lz4.frame
import zstandard
from mcap.records import Schema
from mcap_ros2.decoder import DecoderFactory

from bags.errors import BagError

__all__ = ["McapChannel", "McapIndex", "MessageRef"]

MAGIC = b"\x89MCAP0\r\n"
_OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK, _OP_DATA_END, _OP_FOOTER = 0x03, 0x04, 0x05, 0x06, 0x0F, 0x02
_RECORD = struct.Struct("<BQ")  # opcode, body length
_MESSAGE = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_CHUNK = struct.Struct("<QQQII")  # start, end, uncompressed size, crc, compression string length
_U16, _U32, _U64 = struct.Struct("<H"), struct.Struct("<I"), struct.Struct("<Q")
_STAMP_BYTES = 12  # CDR encapsulation (4) + builtin_interfaces/Time (8)
_CHUNK_CACHE = 4  # decompressed chunks kept (one frame's messages usually share one or two)


@dataclass(frozen=True)
class McapChannel:
    """A channel (topic) with its schema."""

    id: int
    topic: str
    message_encoding: str  # "cdr" for ROS 2
    schema: Schema | None  # None for schemaless channels


@dataclass(frozen=True)
class MessageRef:
    """Where one message's payload lies: ``chunk`` -1 means directly in the file at ``offset``."""

    channel_id: int
    log_time: int  # ns
    stamp_ns: int | None  # header stamp (ns) when the payload starts with a std_msgs/Header, else None
    chunk: int  # index into the compressed-chunk table, or -1
    offset: int  # byte offset of the payload in the file (chunk -1) or in the decompressed chunk
    length: int  # payload bytes


def _decompressor(compression: str) -> Callable[[bytes, int], bytes]:
    if compression == "zstd":
        return lambda data, size: zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
    if compression == "lz4":
        return lambda data, size: lz4.frame.decompress(data)
    raise BagError(f"unsupported MCAP chunk compression {compression!r} (supported: none, zstd, lz4)")


def _header_stamp(head: bytes) -> int | None:
    """Header stamp (ns) from a CDR payload's first 12 bytes; None if they cannot be one."""
    if len(head) < _STAMP_BYTES or head[0] != 0 or head[1] not in (0, 1):
        return None
    sec, nanosec = struct.unpack("<iI" if head[1] == 1 else ">iI", head[4:12])
    return sec * 1_000_000_000 + nanosec if nanosec < 1_000_000_000 else None


class _Buffer:
    """A bounded little-endian cursor over bytes (MCAP strings and records)."""

    def __init__(self, data: bytes | memoryview, where: str) -> None:
        self.data, self.pos, self.where = memoryview(data), 0, where

    def take(self, n: int) -> memoryview:
        if self.pos + n > len(self.data):
            raise BagError(f"{self.where}: record runs past its end (corrupt)")
        out = self.data[self.pos : self.pos + n]
        self.pos += n
        return out

    def u16(self) -> int:
        return _U16.unpack(self.take(2))[0]

    def u32(self) -> int:
        return _U32.unpack(self.take(4))[0]

    def string(self) -> str:
        try:
            return bytes(self.take(self.u32())).decode("utf-8")
        except UnicodeDecodeError as err:
            raise BagError(f"{self.where}: string is not UTF-8 (corrupt)") from err


class McapIndex:
    """Schemas, channels and message positions of one MCAP file (kept open until ``close``)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._fd = os.open(self.path, os.O_RDONLY)
        try:
            self._size = os.fstat(self._fd).st_size
            self._schemas: dict[int, Schema] = {}
            self.channels: dict[int, McapChannel] = {}
            self._pending: dict[int, tuple[int, str, str]] = {}  # channel id -> (schema id, topic, encoding)
            # (file offset, length, uncompressed length, CRC32 of the uncompressed records or 0, compression)
            self._chunks: list[tuple[int, int, int, int, str]] = []
            self._cache: OrderedDict[int, bytes] = OrderedDict()
            self._cache_lock = threading.Lock()  # readers may be called from worker threads
            self.messages: list[MessageRef] = []
            self.truncated_at: int | None = None
            self._walk()
        except BaseException:
            os.close(self._fd)
            raise
        self._factory = DecoderFactory()
        self._decoders: dict[int, Callable[[bytes], Any]] = {}

    # ------------------------------------------------------------------ walking
    def _pread(self, n: int, offset: int) -> bytes:
        return os.pread(self._fd, n, offset)

    def _walk(self) -> None:
        if self._pread(8, 0) != MAGIC:
            raise BagError(f"{self.path} is corrupt or truncated (not an MCAP file: bad magic)")
        pos = 8
        while pos + 9 <= self._size:
            head = self._pread(9 + _MESSAGE.size + _STAMP_BYTES, pos)
            op, length = _RECORD.unpack_from(head)
            body = pos + 9
            if body + length > self._size:
                self.truncated_at = pos
                return
            if op in (_OP_DATA_END, _OP_FOOTER):
                return
            if op == _OP_CHUNK:
                self._walk_chunk(body, length)
            elif op == _OP_MESSAGE:
                self._message(head[9 : 9 + min(length, _MESSAGE.size + _STAMP_BYTES)], body, length, -1)
            elif op in (_OP_SCHEMA, _OP_CHANNEL):
                self._definition(op, self._pread(length, body), f"{self.path} @ {pos}")
            pos = body + length
        self.truncated_at = pos  # ended without a data-end or footer record

    def _walk_chunk(self, body: int, length: int) -> None:
        head = self._pread(_CHUNK.size, body)
        if len(head) < _CHUNK.size or length < _CHUNK.size + 8:
            raise BagError(f"{self.path} @ {body}: chunk header runs past the chunk (corrupt)")
        _, _, uncompressed, crc, clen = _CHUNK.unpack(head)
        if clen > 16:  # "", "zstd", "lz4"
            raise BagError(f"{self.path} @ {body}: chunk compression name of {clen} bytes (corrupt)")
        compression = self._pread(clen, body + _CHUNK.size).decode("utf-8", "replace")
        records_len_at = body + _CHUNK.size + clen
        (records_len,) = _U64.unpack(self._pread(8, records_len_at))
        start = records_len_at + 8
        if start + records_len > body + length:
            raise BagError(f"{self.path} @ {body}: chunk records run past the chunk (corrupt)")
        if compression == "":
            self._walk_records(lambda n, at: self._pread(n, start + at), records_len, -1, start)
            return
        chunk_no = len(self._chunks)
        self._chunks.append((start, records_len, uncompressed, crc, compression))
        data = self._chunk_data(chunk_no)
        self._walk_records(lambda n, at: data[at : at + n], len(data), chunk_no, 0)

    def _walk_records(self, read: Callable[[int, int], bytes], size: int, chunk: int, base: int) -> None:
        """Schemas, channels and messages inside one chunk's records (``read(n, at)``: bytes at ``at``)."""
        pos = 0
        while pos + 9 <= size:
            head = read(9 + _MESSAGE.size + _STAMP_BYTES, pos)  # one read: record header, message header, stamp
            op, length = _RECORD.unpack_from(head)
            body = pos + 9
            if body + length > size:
                raise BagError(f"{self.path}: a record runs past the end of its chunk (corrupt)")
            if op == _OP_MESSAGE:
                self._message(head[9 : 9 + min(length, _MESSAGE.size + _STAMP_BYTES)], base + body, length, chunk)
            elif op in (_OP_SCHEMA, _OP_CHANNEL):
                self._definition(op, read(length, body), f"{self.path} chunk record @ {base + pos}")
            pos = body + length

    def _message(self, head: bytes, body: int, length: int, chunk: int) -> None:
        if length < _MESSAGE.size:
            raise BagError(f"{self.path} @ {body}: message record too short (corrupt)")
        channel_id, _, log_time, _ = _MESSAGE.unpack_from(head)
        stamp = _header_stamp(head[_MESSAGE.size :])
        self.messages.append(
            MessageRef(channel_id, log_time, stamp, chunk, body + _MESSAGE.size, length - _MESSAGE.size)
        )

    def _definition(self, op: int, body: bytes, where: str) -> None:
        b = _Buffer(body, where)
        if op == _OP_SCHEMA:
            sid, name, encoding = b.u16(), b.string(), b.string()
            self._schemas[sid] = Schema(id=sid, name=name, encoding=encoding, data=bytes(b.take(b.u32())))
        else:
            cid, sid, topic, encoding = b.u16(), b.u16(), b.string(), b.string()
            self._pending[cid] = (sid, topic, encoding)
        for cid, (sid, topic, encoding) in list(self._pending.items()):
            if sid == 0 or sid in self._schemas:
                self.channels[cid] = McapChannel(cid, topic, encoding, self._schemas.get(sid))
                del self._pending[cid]

    # ------------------------------------------------------------------ access
    def _chunk_data(self, chunk_no: int) -> bytes:
        with self._cache_lock:
            if chunk_no in self._cache:
                self._cache.move_to_end(chunk_no)
                return self._cache[chunk_no]
        start, length, uncompressed, crc, compression = self._chunks[chunk_no]
        try:
            data = _decompressor(compression)(self._pread(length, start), uncompressed)
        except BagError:
            raise
        except Exception as err:  # zstandard.ZstdError, lz4's RuntimeError
            raise BagError(f"{self.path}: chunk at byte {start} does not decompress ({err})") from err
        if len(data) != uncompressed:
            raise BagError(f"{self.path}: chunk at byte {start} decompresses to {len(data)} of {uncompressed} bytes")
        if crc and zlib.crc32(data) != crc:
            raise BagError(f"{self.path}: chunk at byte {start} fails its CRC check (corrupt)")
        with self._cache_lock:
            self._cache[chunk_no] = data
            if len(self._cache) > _CHUNK_CACHE:
                self._cache.popitem(last=False)
        return data

    def payload(self, ref: MessageRef) -> bytes:
        """The serialised message (CDR for ROS 2)."""
        if ref.chunk < 0:
            data = self._pread(ref.length, ref.offset)
            if len(data) != ref.length:
                raise BagError(f"{self.path}: message at byte {ref.offset} is cut short (file changed?)")
            return data
        return self._chunk_data(ref.chunk)[ref.offset : ref.offset + ref.length]

    def decode(self, ref: MessageRef) -> Any:
        """The message decoded with ``mcap-ros2-support`` (attribute access like rclpy messages)."""
        decoder = self._decoders.get(ref.channel_id)
        if decoder is None:
            ch = self.channels.get(ref.channel_id)
            if ch is None:
                raise BagError(f"{self.path}: message on unknown channel {ref.channel_id}")
            try:
                decoder = self._factory.decoder_for(ch.message_encoding, ch.schema)
            except Exception as err:  # McapROS2DecodeError, or the schema text does not parse
                raise BagError(f"{self.path}: schema of {ch.topic} does not parse ({err})") from err
            if decoder is None:
                raise BagError(f"{self.path}: {ch.topic} is not a ROS 2 CDR channel ({ch.message_encoding!r})")
            self._decoders[ref.channel_id] = decoder
        try:
            return decoder(self.payload(ref))
        except BagError:
            raise
        except Exception as err:  # the CDR decoder raises ValueError / struct.error / IndexError
            raise BagError(f"{self.path}: message at {ref.log_time} ns does not decode ({err})") from err

    def topic_channels(self, topics: Iterable[str]) -> dict[str, list[int]]:
        """Channel ids per topic name (a topic may have several channels)."""
        wanted = set(topics)
        out: dict[str, list[int]] = {t: [] for t in wanted}
        for ch in self.channels.values():
            if ch.topic in wanted:
                out[ch.topic].append(ch.id)
        return out

    def close(self) -> None:
        """Close the file."""
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1
