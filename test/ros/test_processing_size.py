"""The nodes' processing size (``downscale``): colour, depth, labels and intrinsics shrunk as
``sgs-slam run --downscale`` shrinks a dataset, and outputs that say their size."""

from dataclasses import replace

import cv2
import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import CameraInfo, Image

from sgs_slam_core.datasets import DatasetOptions, open_dataset
from sgs_slam_core.datasets.base import auto_downscale
from sgs_slam_ros.frames import AUTO_DOWNSCALE, FrameAssembler
from sgs_slam_ros.messages import camera_info_msg, image_msg
from sgs_slam_ros.slam_node import build_slam_nodes

from ..polling import wait_for
from .helpers import Feeder, Spinner, diagnostics_of, new_context, node_params, shut_down, tiny_frames

pytestmark = pytest.mark.ros


def assemble(frame, downscale: float):
    out, logs, labels = [], [], []
    a = FrameAssembler(
        10, 0, 1000.0, out.append, logs.append, downscale=downscale, on_labels=lambda *x: labels.append(x)
    )
    a.camera_info(camera_info_msg(frame.intrinsics, frame.stamp_ns, "cam"))
    a.image(0, image_msg(frame.rgb, "rgb8", frame.stamp_ns, "cam"))
    a.image(1, image_msg((frame.depth * 1000).round().astype(np.uint16), "16UC1", frame.stamp_ns, "cam"))
    a.label_image(image_msg(frame.labels.astype(np.uint16), "16UC1", frame.stamp_ns, "cam"))
    return a, out, logs, labels


def test_frames_and_their_labels_are_resized_as_the_dataset_reader_does(tiny_scene):
    frame = tiny_frames(tiny_scene)[3]
    a, out, _, labels = assemble(frame, 2.0)
    offline = open_dataset(tiny_scene, options=DatasetOptions(downscale=2.0))[3]
    (got,) = out
    assert got.intrinsics == offline.intrinsics and got.rgb.shape == (24, 32, 3)
    assert got.labels is None  # labels come apart from the frames: tracking never waits for them
    ((stamp, got_labels),) = labels
    assert stamp == frame.stamp_ns and np.array_equal(got_labels, offline.labels)
    assert np.array_equal(got.rgb, offline.rgb)
    assert np.allclose(got.depth, offline.depth, atol=5e-4)  # the node's depth came as millimetres
    assert a.input_size == (64, 48) and a.processing_size == (32, 24)


def test_auto_makes_a_cpus_frames_160_px_wide_and_leaves_a_gpus_at_the_input_size(tiny_scene):
    assert auto_downscale(640, cpu=True) == 4.0 and auto_downscale(848, cpu=True) == 5.3
    assert auto_downscale(64, cpu=True) == 1.0  # never larger than the camera's
    assert auto_downscale(640, cpu=False) == 1.0
    frame = tiny_frames(tiny_scene)[3]
    big = replace(  # the tiny frame as a 320x240 camera gives it
        frame,
        rgb=cv2.resize(frame.rgb, (320, 240), interpolation=cv2.INTER_NEAREST),
        depth=cv2.resize(frame.depth, (320, 240), interpolation=cv2.INTER_NEAREST),
        labels=cv2.resize(frame.labels, (320, 240), interpolation=cv2.INTER_NEAREST),
        intrinsics=frame.intrinsics.scaled(5.0),
    )
    a, out, _, labels = assemble(big, AUTO_DOWNSCALE)
    assert a.downscale == 2.0 and a.input_size == (320, 240) and a.processing_size == (160, 120)
    assert out[0].rgb.shape == (120, 160, 3) and labels[0][1].shape == (120, 160)
    a, out, _, _ = assemble(frame, AUTO_DOWNSCALE)
    assert a.downscale == 1.0 and out[0].rgb.shape == (48, 64, 3)


def test_a_downscale_that_leaves_too_small_a_frame_is_rejected_and_counted(tiny_scene):
    a, out, logs, _ = assemble(tiny_frames(tiny_scene)[0], 4.0)  # 64x48 / 4 = 16x12
    assert out == [] and a.rejected["downscale leaves too small a frame"] == 1
    assert "16x12" in logs[0] and "at least 16x16" in logs[0]


def test_slam_node_tracks_and_renders_at_the_processing_size(tiny_scene):
    frames = tiny_frames(tiny_scene)
    ctx = new_context()
    nodes = build_slam_nodes(context=ctx, parameter_overrides=node_params(downscale=2.0, render_rate_hz=10.0))
    feeder = Feeder(ctx)
    diag, renders, infos = [], [], []
    feeder.create_subscription(DiagnosticArray, "/diagnostics", diag.append, 50)
    feeder.create_subscription(Image, "/mapping_node/render/labels", renders.append, 10)
    feeder.create_subscription(CameraInfo, "/mapping_node/render/camera_info", infos.append, 10)
    spinner = Spinner(ctx, [*nodes, feeder])
    try:
        assert wait_for(feeder.connected, 10.0)
        for frame in frames[:3]:
            feeder.publish(frame)
            assert wait_for(lambda f=frame: f.stamp_ns in feeder.poses, 60.0)
        assert wait_for(lambda: renders and infos, 10.0)
        assert (renders[-1].width, renders[-1].height) == (32, 24)
        assert (infos[-1].width, infos[-1].height) == (32, 24)
        assert infos[-1].k[0] == pytest.approx(frames[0].intrinsics.fx / 2)

        def stamps(msgs: list) -> set[tuple[int, int]]:
            return {(m.header.stamp.sec, m.header.stamp.nanosec) for m in list(msgs)}

        # Each render has its camera_info; the two topics arrive apart, so wait until both have caught up.
        assert wait_for(lambda: stamps(renders) == stamps(infos), 5.0)

        def sized() -> bool:  # a status from before the first frame says n/a: wait for one from after it
            t, m = diagnostics_of(diag, "tracking_node"), diagnostics_of(diag, "mapping_node")
            return bool(t and m) and t[-1][2]["input_size"] != "n/a" and m[-1][2]["render_size"] != "n/a"

        assert wait_for(sized, 5.0)
        _, _, v = diagnostics_of(diag, "tracking_node")[-1]
        assert (v["input_size"], v["processing_size"], v["downscale"]) == ("64x48", "32x24", "2")
        _, _, m = diagnostics_of(diag, "mapping_node")[-1]
        assert m["render_size"] == "32x24"

        def labels_counted() -> bool:  # each label image came apart from its frame and was fused into the map
            _, _, m = diagnostics_of(diag, "mapping_node")[-1]
            return m["labels_in"] == "3" and int(m["labels_fused"]) >= 1 and m["label_latency_ms"] != "n/a"

        assert wait_for(labels_counted, 10.0)
    finally:
        shut_down(ctx, [*nodes, feeder], spinner)
