"""msg_adapters on plain objects (no ROS), rosbags messages and rclpy messages."""

import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from msg_adapters import (
    AdapterError,
    ApproximateSync,
    c2w_to_pose,
    camera_info_fields,
    camera_info_to_intrinsics,
    depth_from_image,
    gaussians_from_cloud,
    gaussians_to_cloud,
    image_fields,
    image_to_numpy,
    labels_from_image,
    pack_rgb,
    pointcloud_fields,
    pointcloud_to_numpy,
    pose_to_c2w,
    rgb_from_image,
    unpack_rgb,
)
from msg_adapters.pointcloud import POINT_DTYPE
from sgs_slam_core.geometry import Intrinsics, se3_exp

from ..core.test_gaussians import make_map


def ns(d):
    """Plain object with the same field names as the message (recursively)."""
    if isinstance(d, dict):
        return SimpleNamespace(**{k: ns(v) for k, v in d.items()})
    if isinstance(d, list) and d and isinstance(d[0], dict):
        return [ns(v) for v in d]
    return d


RNG = np.random.default_rng(0)
ARRAYS = {
    "rgb8": RNG.integers(0, 255, (5, 7, 3), dtype=np.uint8),
    "bgr8": RNG.integers(0, 255, (5, 7, 3), dtype=np.uint8),
    "rgba8": RNG.integers(0, 255, (5, 7, 4), dtype=np.uint8),
    "bgra8": RNG.integers(0, 255, (5, 7, 4), dtype=np.uint8),
    "mono8": RNG.integers(0, 255, (5, 7), dtype=np.uint8),
    "8UC1": RNG.integers(0, 255, (5, 7), dtype=np.uint8),
    "mono16": RNG.integers(0, 65535, (5, 7), dtype=np.uint16),
    "16UC1": RNG.integers(0, 65535, (5, 7), dtype=np.uint16),
    "32FC1": RNG.random((5, 7)).astype(np.float32),
    "32SC1": RNG.integers(0, 2**20, (5, 7), dtype=np.int32),
}


@pytest.mark.parametrize("encoding", sorted(ARRAYS))
def test_image_round_trip_every_encoding(encoding):
    fields = image_fields(ARRAYS[encoding], encoding, 1_500_000_001, "cam")
    assert isinstance(fields["data"], bytes) and fields["header"]["stamp"] == {"sec": 1, "nanosec": 500_000_001}
    assert np.array_equal(image_to_numpy(ns(fields)), ARRAYS[encoding])


def test_row_padding_and_big_endian():
    depth = np.arange(12, dtype=np.uint16).reshape(3, 4) * 1000
    padded = np.zeros((3, 12), np.uint8)  # 8 data bytes per row, 4 bytes of padding
    padded[:, :8] = depth.view(np.uint8).reshape(3, 8)
    msg = SimpleNamespace(height=3, width=4, encoding="16UC1", is_bigendian=0, step=12, data=padded.tobytes())
    assert np.array_equal(image_to_numpy(msg), depth)
    big = SimpleNamespace(
        height=3, width=4, encoding="16UC1", is_bigendian=1, step=8, data=depth.astype(">u2").tobytes()
    )
    assert np.array_equal(image_to_numpy(big), depth)
    assert depth_from_image(big)[2, 3] == pytest.approx(11.0)


def test_conversions_to_rgb_depth_and_labels():
    bgr = ARRAYS["bgr8"]
    assert np.array_equal(rgb_from_image(ns(image_fields(bgr, "bgr8", 0, ""))), bgr[..., ::-1])
    bgra = ARRAYS["bgra8"]
    assert np.array_equal(rgb_from_image(ns(image_fields(bgra, "bgra8", 0, ""))), bgra[..., 2::-1])
    mono = ARRAYS["mono8"]
    assert rgb_from_image(ns(image_fields(mono, "mono8", 0, ""))).shape == (5, 7, 3)
    mm = np.array([[0, 1500], [65535, 20]], np.uint16)
    assert np.allclose(depth_from_image(ns(image_fields(mm, "16UC1", 0, ""))), [[0, 1.5], [65.535, 0.02]])
    metres = np.array([[np.nan, 1.25], [np.inf, -1.0]], np.float32)
    assert depth_from_image(ns(image_fields(metres, "32FC1", 0, ""))).tolist() == [[0.0, 1.25], [0.0, 0.0]]
    ids = np.array([[0, 300], [1163, 40]], np.uint16)  # NYU raw ids above 255 survive
    assert labels_from_image(ns(image_fields(ids, "16UC1", 0, ""))).tolist() == [[0, 300], [1163, 40]]


@pytest.mark.parametrize(
    ("msg", "field"),
    [
        (SimpleNamespace(height=2, width=2, encoding="yuv422", is_bigendian=0, step=4, data=b"\0" * 8), "encoding"),
        (SimpleNamespace(height=2, width=2, encoding="rgb8", is_bigendian=0, step=4, data=b"\0" * 8), "step"),
        (SimpleNamespace(height=2, width=2, encoding="rgb8", is_bigendian=0, step=6, data=b"\0" * 8), "data"),
    ],
)
def test_bad_images_name_the_field(msg, field):
    with pytest.raises(AdapterError, match=f"^{field}:"):
        image_to_numpy(msg)


def test_wrong_kind_of_image_is_refused():
    with pytest.raises(AdapterError, match="encoding: depth must be"):
        depth_from_image(ns(image_fields(ARRAYS["rgb8"], "rgb8", 0, "")))
    with pytest.raises(AdapterError, match="encoding: labels"):
        labels_from_image(ns(image_fields(ARRAYS["32FC1"], "32FC1", 0, "")))
    signed = np.array([[0, 3], [-1, 40]], np.int32)
    with pytest.raises(AdapterError, match=r"^data: label image holds negative"):
        labels_from_image(ns(image_fields(signed, "32SC1", 0, "")))
    assert labels_from_image(ns(image_fields(np.abs(signed), "32SC1", 0, ""))).tolist() == [[0, 3], [1, 40]]


def test_camera_info_round_trip_and_distortion_warning():
    k = Intrinsics(525.0, 526.0, 319.5, 239.5, 640, 480)
    msg = ns(camera_info_fields(k, 5, "cam"))
    got, warnings = camera_info_to_intrinsics(msg)
    assert got == k and warnings == []
    msg.d = [0.1, -0.2, 0.0, 0.0, 0.0]
    assert "rectified" in camera_info_to_intrinsics(msg)[1][0]


def test_pose_round_trip():
    for seed in range(20):
        g = torch.Generator().manual_seed(seed)
        c2w = se3_exp(torch.randn(6, generator=g, dtype=torch.float64) * 2).numpy()
        assert np.allclose(pose_to_c2w(ns(c2w_to_pose(c2w, 1, "map"))), c2w, atol=1e-12)
    with pytest.raises(AdapterError, match="orientation"):
        pose_to_c2w(
            ns({"pose": {"position": {"x": 0, "y": 0, "z": 0}, "orientation": {"x": 0, "y": 0, "z": 0, "w": 0}}})
        )


def test_point_cloud_round_trip_and_rgb_packing():
    rgb = RNG.integers(0, 255, (100, 3), dtype=np.uint8)
    assert np.array_equal(unpack_rgb(pack_rgb(rgb)), rgb)
    assert pack_rgb(np.array([[255, 0, 0]], np.uint8)).view(np.uint32)[0] == 0x00FF0000
    pts = np.zeros(100, dtype=POINT_DTYPE)
    pts["x"], pts["rgb"], pts["label"] = RNG.random(100), pack_rgb(rgb), np.arange(100)
    back = pointcloud_to_numpy(ns(pointcloud_fields(pts, 0, "map")))
    assert back.dtype.names == POINT_DTYPE.names and np.array_equal(back.tobytes(), pts.tobytes())


@pytest.mark.parametrize("anisotropic", [False, True])
def test_gaussian_cloud_round_trip_is_exact(anisotropic):
    m = make_map(40, s=5, anisotropic=anisotropic)
    back = gaussians_from_cloud(pointcloud_to_numpy(ns(pointcloud_fields(gaussians_to_cloud(m), 0, "map"))))
    for name, tensor in m.state_dict().items():
        assert torch.equal(getattr(back, name), tensor), name


def test_sync_exact_and_approximate():
    exact = ApproximateSync(3, queue_size=5, slop_ns=0)
    assert exact.push(0, 100, "rgb") is None
    assert exact.push(1, 100, "depth") is None
    assert exact.push(2, 100, "labels") == (100, ["rgb", "depth", "labels"])
    approx = ApproximateSync(2, queue_size=5, slop_ns=10)
    approx.push(0, 100, "a100")
    approx.push(0, 133, "a133")
    assert approx.push(1, 131, "b131") == (133, ["a133", "b131"])
    assert approx.dropped == 1 and approx.dropped_by_input == [1, 0]  # a100 can no longer be matched
    assert approx.push(1, 170, "b170") is None and approx.push(0, 200, "a200") is None  # 30 ns apart: no match
    assert approx.pending(0) == 1 and approx.pending(1) == 1
    approx.clear()
    assert approx.dropped_by_input == [2, 1] and approx.pending(0) == 0
    tight = ApproximateSync(2, queue_size=2, slop_ns=0)
    for t in (1, 2, 3):
        tight.push(0, t, t)
    assert tight.dropped == 1 and tight.dropped_by_input == [1, 0]  # queue overflow


def test_rosbags_messages_are_read_too():
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    image_cls, header_cls, time_cls = (
        ts.types[n] for n in ("sensor_msgs/msg/Image", "std_msgs/msg/Header", "builtin_interfaces/msg/Time")
    )
    arr = ARRAYS["16UC1"]
    msg = image_cls(
        header=header_cls(stamp=time_cls(sec=1, nanosec=2), frame_id="cam"),
        height=5,
        width=7,
        encoding="16UC1",
        is_bigendian=0,
        step=14,
        data=arr.view(np.uint8).reshape(-1),
    )
    assert np.array_equal(image_to_numpy(msg), arr)
    assert math.isclose(float(depth_from_image(msg)[0, 0]), arr[0, 0] / 1000, rel_tol=1e-6)
