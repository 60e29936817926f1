"""An input that stays silent while the others arrive is a warning in /diagnostics and one log line."""

import dataclasses
import time

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import Log
from rclpy.parameter import Parameter

from sgs_slam_ros.slam_node import build_slam_nodes

from ..polling import wait_for
from .helpers import Feeder, Spinner, diagnostics_of, new_context, node_params, shut_down, tiny_frames

pytestmark = pytest.mark.ros
OK, WARN = 0, 1


def test_missing_label_topic_is_reported_once_and_clears(tiny_scene):
    frames = tiny_frames(tiny_scene)
    ctx = new_context()
    nodes = build_slam_nodes(context=ctx, parameter_overrides=node_params(stale_input_s=1.0))  # use_semantics: true
    feeder = Feeder(ctx)
    diag, logs = [], []
    feeder.create_subscription(DiagnosticArray, "/diagnostics", diag.append, 50)
    feeder.create_subscription(Log, "/rosout", logs.append, 100)
    spinner = Spinner(ctx, [*nodes, feeder])
    try:
        assert wait_for(feeder.connected, 10.0)
        # a camera driver without the segmentation node: colour, depth and camera_info only, for 3 s
        end, i = time.monotonic() + 3.0, 0
        while time.monotonic() < end:
            feeder.publish(dataclasses.replace(frames[0], stamp_ns=(i + 1) * 10**8), semantic=False)
            i += 1
            time.sleep(0.1)

        def newest_warning() -> tuple[int, str, dict[str, str]] | None:
            """The newest status that warns of the labels (statuses come once a second; once the feed ends
            a later one says that no input comes at all)."""
            warnings = [st for st in diagnostics_of(diag, "tracking_node") if st[0] == WARN and "no labels" in st[1]]
            return warnings[-1] if warnings else None

        assert wait_for(lambda: newest_warning() is not None, 3.0), diagnostics_of(diag, "tracking_node")[-3:]
        _, message, values = newest_warning()
        assert "/semantic/image" in message, message
        assert values["silent_inputs"] == "/semantic/image"
        assert int(values["frames_in"]) >= 5 and int(values["frames_tracked"]) >= 1  # frames never wait for labels
        assert wait_for(lambda: any(m.name == "tracking_node" and "is silent" in m.msg for m in logs), 2.0)
        warnings = [m.msg for m in logs if m.name == "tracking_node" and "is silent" in m.msg]
        assert len(warnings) == 1, warnings  # once, not once a second
        assert "/semantic/image" in warnings[0] and "use_semantics:=false" in warnings[0]
        # the segmentation node starts: frames flow and the warning clears (stale_input_s is live: longer
        # now, so the camera that stops after two frames is not yet "no input" when the status is read)
        nodes[0].set_parameters([Parameter("stale_input_s", value=5.0)])
        for frame in frames[:2]:
            f = dataclasses.replace(frame, stamp_ns=frame.stamp_ns + i * 10**8)
            feeder.publish(f)
            assert wait_for(lambda f=f: f.stamp_ns in feeder.poses, 60.0)
        assert wait_for(lambda: diagnostics_of(diag, "tracking_node")[-1][0] == OK, 5.0)
        assert diagnostics_of(diag, "tracking_node")[-1][2]["silent_inputs"] == "none"
    finally:
        shut_down(ctx, [*nodes, feeder], spinner)
