"""Outputs are driven by work done: a render per mapped frame, latched clouds, no stall under use_sim_time."""

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import Image, PointCloud2

from msg_adapters import stamp_to_ns
from sgs_slam_ros.qos import latched_qos
from sgs_slam_ros.slam_node import build_slam_nodes

from ..polling import wait_for
from .helpers import Feeder, Spinner, diagnostics_of, new_context, node_params, shut_down, tiny_frames

pytestmark = pytest.mark.ros
CAM = "rig_color_optical_frame"


@pytest.fixture
def start():
    started = []

    def _start(**params):
        ctx = new_context()
        nodes = build_slam_nodes(context=ctx, parameter_overrides=node_params(**params))
        feeder = Feeder(ctx)
        received = {"color": [], "depth": [], "diag": []}
        feeder.create_subscription(Image, "/mapping_node/render/color", received["color"].append, 50)
        feeder.create_subscription(Image, "/mapping_node/render/depth", received["depth"].append, 50)
        feeder.create_subscription(DiagnosticArray, "/diagnostics", received["diag"].append, 50)
        spinner = Spinner(ctx, [*nodes, feeder])
        started.append((ctx, spinner, [*nodes, feeder]))
        assert wait_for(feeder.connected, 10.0)
        return nodes, feeder, received

    yield _start
    for ctx, spinner, nodes in started:
        shut_down(ctx, nodes, spinner)


def play(feeder, frames):
    for f in frames:
        feeder.publish(f, frame_id=CAM)
        assert wait_for(lambda f=f: f.stamp_ns in feeder.poses, 60.0), f"no pose for frame {f.index}"


def test_one_render_per_mapped_frame_with_its_stamp_and_frame_id(start, tiny_scene):
    frames = tiny_frames(tiny_scene)[:5]
    nodes, feeder, received = start(render_rate_hz=30.0)
    mapping = nodes[1]
    play(feeder, frames)
    assert mapping.pipeline.wait_idle(30.0)
    assert wait_for(
        lambda: received["color"] and stamp_to_ns(received["color"][-1].header.stamp) == frames[-1].stamp_ns, 5.0
    )
    assert not wait_for(lambda: len(received["color"]) > len(frames), 1.5)  # nothing re-sent while idle
    stamps = [stamp_to_ns(m.header.stamp) for m in received["color"]]
    assert len(set(stamps)) == len(stamps), "a frame was rendered twice"
    assert set(stamps) <= {f.stamp_ns for f in frames}  # each render is a mapped frame's view
    assert stamps == sorted(stamps)
    assert {m.header.frame_id for m in received["color"] + received["depth"]} == {CAM}  # the input's frame id
    # ~/points is latched like ~/gaussians: a viewer that starts now gets the map at once
    late = []
    feeder.create_subscription(PointCloud2, "/mapping_node/points", late.append, latched_qos())
    assert wait_for(lambda: late, 5.0), "~/points is not latched"
    assert late[-1].width == mapping.pipeline.slam.num_gaussians and late[-1].header.frame_id == "map"
    assert stamp_to_ns(late[-1].header.stamp) == frames[-1].stamp_ns


def test_outputs_and_diagnostics_do_not_stall_under_use_sim_time(start, tiny_scene):
    """With use_sim_time and no /clock (a bag that ended, or none yet) ROS time stands still."""
    frames = tiny_frames(tiny_scene)[:3]
    nodes, feeder, received = start(use_sim_time=True, render_rate_hz=10.0, points_rate_hz=10.0)
    assert nodes[1].get_clock().now().nanoseconds == 0  # the sim clock is stopped
    assert wait_for(lambda: len(diagnostics_of(received["diag"], "mapping_node")) >= 2, 5.0)
    play(feeder, frames)
    assert wait_for(
        lambda: received["color"] and stamp_to_ns(received["color"][-1].header.stamp) == frames[-1].stamp_ns, 10.0
    )
    assert wait_for(lambda: diagnostics_of(received["diag"], "tracking_node")[-1][2]["frames_tracked"] == "3", 5.0)
    assert diagnostics_of(received["diag"], "tracking_node")[-1][2]["frames_in"] == "3"
    held = {"gaussians", "gaussian_mb", "keyframes", "keyframe_mb", "keyframes_evicted"}  # the memory held
    assert wait_for(lambda: diagnostics_of(received["diag"], "mapping_node")[-1][2]["keyframes"] == "1", 5.0)
    assert held <= diagnostics_of(received["diag"], "mapping_node")[-1][2].keys()
