"""McapIndex against the mcap library's reader; the zero-copy Image decoder against mcap-ros2's."""

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.records import Schema
from mcap.writer import CompressionType, Writer
from mcap_ros2.decoder import DecoderFactory
from rosbags.typesys import Stores, get_typestore

from bags import BagError, convert, open_bag
from bags import rosbags_messages as rm
from bags.cdr_image import decode_image
from bags.info import bag_info
from bags.mcap_index import McapIndex
from msg_adapters import depth_from_image, image_fields, rgb_from_image
from sgs_slam_core.datasets import open_dataset

TS = get_typestore(Stores.ROS2_JAZZY)
IMAGE = "sensor_msgs/msg/Image"


def image_cdr(arr, encoding, stamp_ns, frame_id, little_endian=True):
    return bytes(
        TS.serialize_cdr(
            rm.image(TS, image_fields(arr, encoding, stamp_ns, frame_id)), IMAGE, little_endian=little_endian
        )
    )


def make_schema():
    return Schema(id=1, name=IMAGE, encoding="ros2msg", data=TS.generate_msgdef(IMAGE, ros_version=2)[0].encode())


def write_mcap(path, compression, chunking=True, count=6):
    """Images on two topics written with the mcap library (lz4/zstd/none chunks, or no chunks at all)."""
    schema_text = TS.generate_msgdef(IMAGE, ros_version=2)[0]
    rng = np.random.default_rng(1)
    sent = []
    with path.open("wb") as f:
        w = Writer(f, chunk_size=20_000, compression=compression, use_chunking=chunking)
        w.start("ros2", "test")
        sid = w.register_schema(IMAGE, "ros2msg", schema_text.encode())
        chans = [w.register_channel(t, "cdr", sid) for t in ("/a", "/b")]
        for i in range(count):
            for c in chans:
                data = image_cdr(rng.integers(0, 255, (30, 41, 3), dtype=np.uint8), "rgb8", 10**9 + i * 10**7, "f" * i)
                w.add_message(c, log_time=1000 + i, publish_time=1000 + i, data=data, sequence=i)
                sent.append((c, 1000 + i, data))
        w.finish()
    return sent


@pytest.mark.parametrize(
    ("compression", "chunking"),
    [
        (CompressionType.NONE, True),
        (CompressionType.ZSTD, True),
        (CompressionType.LZ4, True),
        (CompressionType.NONE, False),
    ],
)
def test_index_finds_every_payload_like_the_mcap_reader(tmp_path, compression, chunking):
    path = tmp_path / "x.mcap"
    sent = write_mcap(path, compression, chunking)
    index = McapIndex(path)
    try:
        assert index.truncated_at is None
        assert sorted(ch.topic for ch in index.channels.values()) == ["/a", "/b"]
        assert index.channels[sent[0][0]].schema.name == IMAGE
        got = [(m.channel_id, m.log_time, index.payload(m)) for m in index.messages]
        assert got == sent
        with path.open("rb") as f:
            theirs = [(c.id, m.log_time, m.data) for _, c, m in make_reader(f).iter_messages(log_time_order=False)]
        assert sorted(got) == sorted(theirs)
        assert [m.stamp_ns for m in index.messages[:2]] == [10**9, 10**9]
        decoded = index.decode(index.messages[-1])
        assert decoded.header.frame_id == "f" * 5 and decoded.width == 41
    finally:
        index.close()


def test_truncated_file_is_reported_and_garbage_refused(tmp_path):
    path = tmp_path / "x.mcap"
    write_mcap(path, CompressionType.NONE)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    index = McapIndex(path)
    assert index.truncated_at is not None and 0 < len(index.messages) < 12
    index.close()
    info = bag_info(path)  # the footer is gone: counted from the complete chunks
    assert info.truncated_at == index.truncated_at
    assert sum(t.count for t in info.topics) == len(index.messages)
    assert {t.encoding for t in info.topics} == {"rgb8"} and info.topics[0].size == "41x30"
    path.write_bytes(b"garbage" * 10)
    with pytest.raises(BagError, match="not an MCAP file"):
        McapIndex(path)


@pytest.mark.parametrize("little_endian", [True, False])
@pytest.mark.parametrize(("encoding", "dtype", "shape"), [("rgb8", np.uint8, (5, 7, 3)), ("16UC1", np.uint16, (6, 9))])
def test_cdr_image_matches_the_generic_decoder(encoding, dtype, shape, little_endian):
    arr = np.arange(np.prod(shape), dtype=dtype).reshape(shape)
    for frame_id in ("", "c", "abc", "camera_color_optical_frame"):  # every string length modulo 4
        payload = image_cdr(arr, encoding, 1_234_567_890_123, frame_id, little_endian)
        ours = decode_image(payload)
        theirs = DecoderFactory().decoder_for("cdr", make_schema())(payload)
        for field in ("height", "width", "encoding", "is_bigendian", "step"):
            assert getattr(ours, field) == getattr(theirs, field)
        assert bytes(ours.data) == bytes(theirs.data)
        assert ours.header.frame_id == theirs.header.frame_id == frame_id
        assert (ours.header.stamp.sec, ours.header.stamp.nanosec) == (1234, 567_890_123)
    assert isinstance(decode_image(payload).data, memoryview)  # a view of the payload, not a copy


def test_cdr_image_rejects_malformed_payloads():
    payload = image_cdr(np.zeros((4, 4, 3), np.uint8), "rgb8", 0, "c")
    with pytest.raises(ValueError, match="ends inside"):
        decode_image(payload[:-5])
    with pytest.raises(ValueError, match="CDR"):
        decode_image(b"\x00\x07\x00\x00" + payload[4:])


def test_bag_reader_decodes_zstd_and_plain_bags_alike(tiny_scene, tmp_path):
    ds = open_dataset(tiny_scene)
    for compress in (False, True):
        convert(ds, tmp_path / f"b{compress}", compress=compress)
    plain, packed = open_bag(tmp_path / "bFalse"), open_bag(tmp_path / "bTrue")
    for i in range(len(ds)):
        a, b, c = ds[i], plain[i], packed[i]
        assert np.array_equal(a.rgb, b.rgb) and np.array_equal(b.rgb, c.rgb) and b.rgb.flags.writeable
        assert np.array_equal(b.depth, c.depth) and np.abs(a.depth - b.depth).max() <= 0.0005 + 1e-6
        assert np.array_equal(a.labels, b.labels) and np.array_equal(b.labels, c.labels)
    plain.close()
    packed.close()


def test_image_topic_with_another_type_is_refused(tmp_path):
    path = tmp_path / "bag"
    path.mkdir()
    schema_text = TS.generate_msgdef("sensor_msgs/msg/CameraInfo", ros_version=2)[0]
    with (path / "x.mcap").open("wb") as f:
        w = Writer(f)
        w.start("ros2", "test")
        sid = w.register_schema("sensor_msgs/msg/CameraInfo", "ros2msg", schema_text.encode())
        for topic in ("/camera/color/image_raw", "/camera/depth/image_raw", "/camera/color/camera_info"):
            cid = w.register_channel(topic, "cdr", sid)
            w.add_message(cid, log_time=1, publish_time=1, data=b"\x00\x01\x00\x00" + bytes(8), sequence=0)
        w.finish()
    with pytest.raises(BagError, match="expected sensor_msgs/msg/Image"):
        open_bag(path)


def test_depth_from_a_cdr_view_equals_the_copied_decode():
    depth = (np.arange(48, dtype=np.uint16) * 37).reshape(6, 8)
    payload = image_cdr(depth, "16UC1", 0, "d")
    theirs = DecoderFactory().decoder_for("cdr", make_schema())(payload)
    assert np.array_equal(depth_from_image(decode_image(payload)), depth_from_image(theirs))
    rgb = np.arange(72, dtype=np.uint8).reshape(4, 6, 3)
    assert np.array_equal(rgb_from_image(decode_image(image_cdr(rgb, "rgb8", 0, "x"))), rgb)


def test_corrupt_compressed_chunk_is_a_bag_error(tmp_path):
    path = tmp_path / "x.mcap"
    write_mcap(path, CompressionType.ZSTD)
    data = bytearray(path.read_bytes())
    middle = len(data) // 3
    data[middle : middle + 64] = bytes(64)  # zero a run inside the first chunk's compressed records
    path.write_bytes(bytes(data))
    with pytest.raises(BagError, match=r"corrupt|decompress"):
        McapIndex(path)
