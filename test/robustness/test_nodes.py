"""slam_node under hostile input: a flood of frames, label ids far above num_classes, images whose step
and size disagree. The node must count what it drops, keep its memory bounded and keep working."""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import Image

from msg_adapters import AdapterError, labels_from_image
from sgs_slam_core.datasets import open_dataset
from sgs_slam_ros.messages import camera_info_msg, header, image_msg
from sgs_slam_ros.slam_node import build_slam_nodes

from ..polling import wait_for
from ..ros.helpers import FAST, Feeder, Spinner, new_context, node_params, shut_down

pytestmark = pytest.mark.ros
CAM = "camera_color_optical_frame"


def rss_mb() -> float:
    """Resident memory of this process now (MB)."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * 4096 / 2**20


@pytest.fixture(scope="module")
def frames(tiny_scene):
    ds = open_dataset(tiny_scene)
    return [
        dataclasses.replace(ds[i], depth=(np.round(ds[i].depth * 1000) / 1000).astype(np.float32))
        for i in range(len(ds))
    ]


def start(tmp_path, **params):
    ctx = new_context()
    nodes = build_slam_nodes(
        context=ctx, parameter_overrides=node_params(map_path=str(tmp_path / "m.sgsmap"), **params)
    )
    feeder = Feeder(ctx)
    diags: list[DiagnosticArray] = []
    feeder.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 50)
    spinner = Spinner(ctx, [*nodes, feeder])
    assert wait_for(feeder.connected, 10.0), "slam_node did not subscribe"
    return ctx, nodes, feeder, diags, spinner


def stop(ctx, nodes, feeder, spinner):
    shut_down(ctx, [*nodes, feeder], spinner)


def latest_values(diags, node="tracking_node"):
    for array in reversed(diags):
        for status in array.status:
            if status.name.endswith(node):
                return {kv.key: kv.value for kv in status.values}
    return {}


def at(frame, t_ns):
    return dataclasses.replace(frame, stamp_ns=t_ns)


def publish_raw(feeder, frame, t_ns, rgb: Image | None = None, semantic: Image | None = None) -> None:
    """``frame`` at ``t_ns`` with the colour and/or label message replaced by hand-made ones."""
    feeder.info_pub.publish(camera_info_msg(frame.intrinsics, t_ns, CAM))
    if rgb is not None:
        rgb.header = header(t_ns, CAM)
    feeder.pubs["/rgb/image"].publish(rgb or image_msg(frame.rgb, "rgb8", t_ns, CAM))
    feeder.pubs["/depth/image"].publish(image_msg((frame.depth * 1000).round().astype("uint16"), "16UC1", t_ns, CAM))
    feeder.pubs["/semantic/image"].publish(semantic or image_msg(frame.labels.astype("uint16"), "16UC1", t_ns, CAM))


@pytest.mark.parametrize("qos", ["best_effort", "reliable"])
def test_a_flood_is_dropped_and_counted_with_bounded_memory(tmp_path, frames, qos):
    """400 frames as fast as they can be published into a live (not lockstep) node."""
    ctx, nodes, feeder, diags, spinner = start(tmp_path, lockstep=False, input_qos=qos)
    tracking = nodes[0]
    try:
        t = 10**9
        for i in range(24):  # warm up: the map exists and has stopped growing fast
            t += 33_000_000
            feeder.publish(at(frames[i % len(frames)], t))
            assert wait_for(lambda t=t: t in feeder.poses, 30.0)
        before = rss_mb()
        published = 400
        for i in range(published):
            t += 33_000_000
            feeder.publish(at(frames[i % len(frames)], t))
        assert wait_for(tracking.pipeline.idle, 60.0)
        after = rss_mb()
        t += 33_000_000  # still alive: a frame at a normal pace gets its pose (and closes the stamps' gap)
        feeder.publish(at(frames[0], t))
        assert wait_for(lambda: t in feeder.poses, 30.0)
        st, sync = tracking.pipeline.stats, tracking.assembler.sync
        lost_in_transport = tracking.camera.gaps["rgb"].lost  # best effort: DDS may drop them before the node
        print(
            f"flood: {published} published, {st.frames_in} assembled, {st.tracked} tracked, "
            f"{st.dropped_frames} dropped by the pipeline, {sync.dropped} by the synchroniser, "
            f"{lost_in_transport} lost in transport; RSS {before:.0f} -> {after:.0f} MB"
        )
        # every input queue stayed bounded, whatever arrived
        assert len(tracking.pipeline._frames) <= 1 and len(tracking.assembler._waiting) <= 10
        assert all(len(q) <= sync.queue_size for q in sync._queues)
        assert st.tracked < 24 + published  # the node could not keep up: it dropped frames ...
        counted = st.dropped_frames + sync.dropped + (lost_in_transport if qos == "best_effort" else 0)
        assert counted > 0  # ... and counted them
        assert after - before < 300, f"resident memory grew {after - before:.0f} MB over {published} frames"

        def reported() -> bool:
            values = latest_values(diags)
            return (
                bool(values)
                and int(values["frames_dropped"]) >= st.dropped_frames
                and int(values["frames_lost"]) >= (lost_in_transport if qos == "best_effort" else 0)
                and int(values["frames_dropped"]) + int(values["frames_lost"]) > 0
            )

        assert wait_for(reported, 5.0), latest_values(diags)
    finally:
        stop(ctx, nodes, feeder, spinner)


@pytest.mark.parametrize("mode", ["color", "onehot"])
def test_label_ids_far_above_num_classes_never_kill_the_node(tmp_path, frames, mode):
    overrides = [*FAST, f"semantic.mode={mode}"]
    ctx, nodes, feeder, _, spinner = start(tmp_path, overrides=overrides)
    tracking, mapping = nodes
    slam = tracking.pipeline.slam
    try:
        t = 10**9
        for i in range(3):
            t += 33_000_000
            feeder.publish(at(frames[i], t))
            assert wait_for(lambda t=t: t in feeder.poses, 30.0)
        # 16-bit ids far above num_classes (41): a colour-mode map takes them, one-hot drops the frame
        big = frames[3].labels.copy()
        big[::2, ::2] = 60000
        t += 33_000_000
        feeder.publish(dataclasses.replace(frames[3], labels=big, stamp_ns=t))
        # 32-bit ids no image format of ours can hold: refused at the message boundary
        huge = frames[4].labels.astype(np.int32)
        huge[0, 0] = 2**30
        t += 33_000_000
        publish_raw(feeder, frames[4], t, semantic=image_msg(huge, "32SC1", t, CAM))
        assert wait_for(lambda: tracking.assembler.rejected["wrong encoding or bad image"] == 1, 10.0)
        for i in range(5, 8):  # normal frames go on being tracked, mapped and rendered
            t += 33_000_000
            feeder.publish(at(frames[i], t))
            assert wait_for(lambda t=t: t in feeder.poses, 30.0)
        assert mapping.pipeline.wait_idle(30.0)
        assert slam.num_gaussians > 0 and max(slam.label_candidates()) <= 60000
        errors_before = tracking.pipeline.stats.errors
        view = slam.render_view(slam.last_c2w)
        decoded = slam.decode(view.semantic)  # decoding with the far ids among the candidates works
        assert decoded.shape == (48, 64) and int(decoded.max()) < (41 if mode == "onehot" else 60001)
        t += 33_000_000
        feeder.publish(at(frames[8], t))
        assert wait_for(lambda: t in feeder.poses, 30.0)
        assert tracking.pipeline.stats.errors == errors_before  # nothing keeps failing after the bad frames
        if mode == "onehot":
            assert "num_classes" in tracking.pipeline.stats.last_error
    finally:
        stop(ctx, nodes, feeder, spinner)


def raw_image(t_ns: int, width: int, height: int, encoding: str, step: int, data: bytes) -> Image:
    return Image(
        header=header(t_ns, CAM), height=height, width=width, encoding=encoding, is_bigendian=0, step=step, data=data
    )


def test_step_and_size_that_disagree_are_dropped_and_counted(tmp_path, frames):
    ctx, nodes, feeder, diags, spinner = start(tmp_path)
    tracking = nodes[0]
    try:
        t = 10**9
        for i in range(2):
            t += 33_000_000
            feeder.publish(at(frames[i], t))
            assert wait_for(lambda t=t: t in feeder.poses, 30.0)
        f = frames[2]
        rgb = f.rgb.tobytes()
        bad_rgb = [
            raw_image(0, 64, 48, "rgb8", 64, rgb),  # step shorter than a row (64 x 3 bytes)
            raw_image(0, 64, 48, "rgb8", 192, rgb[:1000]),  # data shorter than step x height
            raw_image(0, 60_000, 60_000, "rgb8", 180_000, rgb),  # a huge header over a small buffer
        ]
        for msg in bad_rgb:
            t += 33_000_000
            publish_raw(feeder, f, t, rgb=msg)
        assert wait_for(lambda: tracking.assembler.rejected["wrong encoding or bad image"] == 3, 10.0)
        t += 33_000_000
        padded = np.zeros((48, 64 * 3 + 8), np.uint8)  # a valid padded step is read past its padding
        padded[:, : 64 * 3] = f.rgb.reshape(48, -1)
        publish_raw(feeder, f, t, rgb=raw_image(t, 64, 48, "rgb8", 64 * 3 + 8, padded.tobytes()))
        assert wait_for(lambda: t in feeder.poses, 30.0)

        def reported() -> bool:
            values = latest_values(diags)
            return bool(values) and values.get("dropped[wrong encoding or bad image]") == "3"

        assert wait_for(reported, 5.0), latest_values(diags)
    finally:
        stop(ctx, nodes, feeder, spinner)


def test_label_adapter_bounds_ids_without_a_pass_for_narrow_encodings():
    ok = image_msg(np.full((4, 5), 65535, np.uint16), "16UC1", 0, CAM)
    assert labels_from_image(ok).max() == 65535
    wide = image_msg(np.full((4, 5), 70000, np.int32), "32SC1", 0, CAM)
    with pytest.raises(AdapterError, match="class id 70000 > 65535"):
        labels_from_image(wide)
    assert labels_from_image(wide, max_id=100000).max() == 70000
    with pytest.raises(AdapterError, match="class id 300 > 255"):
        labels_from_image(image_msg(np.full((2, 2), 300, np.uint16), "16UC1", 0, CAM), max_id=255)
    negative = image_msg(np.full((2, 2), -1, np.int32), "32SC1", 0, CAM)
    with pytest.raises(AdapterError, match="negative"):
        labels_from_image(negative)


@pytest.mark.parametrize(
    ("param", "message"),
    [
        ("preset:=nope", "unknown preset 'nope'"),
        ("overrides:=[tracking.adam.iterations=abc]", "tracking.adam.iterations: expected an integer, got 'abc'"),
        ("config_file:=/nonexistent/cfg.yaml", "cannot read config file /nonexistent/cfg.yaml"),
    ],
)
def test_a_bad_configuration_stops_the_node_with_one_line(param, message):
    env = {**os.environ, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    proc = subprocess.run(
        [sys.executable, "-m", "sgs_slam_ros.slam_node", "--ros-args", "-p", param],
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
        check=False,
    )
    err = proc.stderr.strip()
    assert proc.returncode == 1 and "Traceback" not in err, err
    assert message in err.splitlines()[-1], err
