"""Parameters: every one has a value and a description over GetParameters, live ones apply, bad ones say why."""

import os
import random
import subprocess
import sys
from pathlib import Path

import pytest
import rclpy
import torch
from rcl_interfaces.msg import ParameterType
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from sensor_msgs.msg import Image

from sgs_slam_ros.params import COMMON, EDIT, MAPPING, TRACKING, declare, use_threads
from sgs_slam_ros.slam_node import build_slam_nodes, main

from ..polling import wait_for
from .helpers import Feeder, Spinner, new_context, node_params, shut_down, tiny_frames

pytestmark = pytest.mark.ros


@pytest.fixture
def system():
    ctx = new_context()
    nodes = build_slam_nodes(context=ctx, parameter_overrides=node_params(render_rate_hz=20.0))
    feeder = Feeder(ctx)
    spinner = Spinner(ctx, [*nodes, feeder])
    assert wait_for(feeder.connected, 10.0)
    yield nodes, feeder
    shut_down(ctx, [*nodes, feeder], spinner)


def done(future, timeout=10.0):
    assert wait_for(future.done, timeout), "the parameter service did not answer"
    return future.result()


def set_params(client, **values):
    result = done(client.set_parameters([Parameter(k.replace("__", "."), value=v) for k, v in values.items()]))
    return [(r.successful, r.reason) for r in result.results]


@pytest.mark.parametrize(
    "node_name,specs", [("/tracking_node", COMMON + TRACKING), ("/mapping_node", COMMON + MAPPING + EDIT)]
)
def test_every_parameter_has_a_value_and_a_description_over_the_services(system, node_name, specs):
    _, feeder = system
    client = AsyncParameterClient(feeder, node_name)
    assert client.wait_for_services(timeout_sec=10.0)
    names = list(done(client.list_parameters()).result.names)
    assert {s.name for s in specs} <= set(names)
    values = done(client.get_parameters(names)).values
    assert len(values) == len(names)
    unset = [n for n, v in zip(names, values, strict=True) if v.type == ParameterType.PARAMETER_NOT_SET]
    assert not unset, f"parameters without a value: {unset}"
    by_name = dict(zip(names, values, strict=True))
    assert by_name["preset"].string_value == "synthetic"
    assert list(by_name["overrides"].string_array_value) == ["tracking.adam.iterations=15", "mapping.iterations=8"]
    described = done(client.describe_parameters([s.name for s in specs])).descriptors
    assert all(d.description for d in described)
    assert {d.name for d in described if d.read_only} == {s.name for s in specs if s.read_only}


def test_live_parameters_apply_and_read_only_ones_refuse(system, tiny_scene):
    nodes, feeder = system
    tracking, mapping = nodes
    renders = []
    feeder.create_subscription(Image, "/mapping_node/render/color", renders.append, 50)
    mapper = AsyncParameterClient(feeder, "/mapping_node")
    tracker = AsyncParameterClient(feeder, "/tracking_node")
    assert mapper.wait_for_services(timeout_sec=10.0) and tracker.wait_for_services(timeout_sec=10.0)
    frames = tiny_frames(tiny_scene)

    def play(fs):
        for f in fs:
            feeder.publish(f)
            assert wait_for(lambda f=f: f.stamp_ns in feeder.poses, 60.0)
        assert mapping.pipeline.wait_idle(30.0)

    # renders off at runtime: nothing more is rendered
    assert set_params(mapper, render_rate_hz=0.0) == [(True, "")]
    play(frames[:3])
    assert not wait_for(lambda: renders, 1.5) and mapping.renders.count == 0
    # and on again: the newest mapped frame is rendered, once
    assert set_params(mapper, render_rate_hz=20.0) == [(True, "")]
    assert wait_for(lambda: renders, 5.0)
    assert not wait_for(lambda: len(renders) > 1, 1.0)  # no re-sends without a new mapped frame
    assert renders[0].header.stamp == feeder.poses[frames[2].stamp_ns].header.stamp
    # live values reach the code that uses them
    assert set_params(tracker, sync_slop_s=0.05, depth_scale=5000.0, path_max_length=2) == [(True, "")] * 3
    assert tracking.assembler.sync.slop_ns == 50_000_000 and tracking.assembler.depth_scale == 5000.0
    assert set_params(tracker, depth_scale=1000.0) == [(True, "")]
    play(frames[3:5])
    assert len(tracking.path) == 2
    # the path off at runtime: poses are still kept but not published; on again: published once
    assert set_params(tracker, path_rate_hz=0.0) == [(True, "")]
    sent = tracking.path_out.count
    play(frames[5:7])
    assert not wait_for(lambda: tracking.path_out.count > sent, 1.0)
    assert set_params(tracker, path_rate_hz=20.0) == [(True, "")]
    assert wait_for(lambda: tracking.path_out.count == sent + 1, 5.0)
    assert not wait_for(lambda: tracking.path_out.count > sent + 1, 0.5)  # no re-sends without a new pose
    # refusals name the reason
    ((ok, why),) = set_params(tracker, preset="replica")
    assert not ok and "read-only" in why
    ((ok, why),) = set_params(tracker, depth_scale=1000)
    assert not ok and "type" in why.lower()
    ((ok, why),) = set_params(mapper, render_rate_hz=100.0)
    assert not ok and ("range" in why or "bound" in why)
    ((ok, why),) = set_params(mapper, edit__remove_labels=5)
    assert not ok and "expected a list of strings" in why
    assert done(tracker.get_parameters(["preset", "depth_scale"])).values[1].double_value == 1000.0


def test_an_integer_given_at_start_up_for_a_floating_point_parameter_is_that_number():
    ctx = new_context()
    given = [Parameter("downscale", Parameter.Type.INTEGER, 2), Parameter("depth_scale", Parameter.Type.INTEGER, 5000)]
    node = rclpy.create_node("int_params", context=ctx, parameter_overrides=given)
    try:
        values = declare(node, COMMON + TRACKING)
        assert values["downscale"] == 2.0 and isinstance(values["downscale"], float)
        assert node.get_parameter("depth_scale").type_ == Parameter.Type.DOUBLE and values["depth_scale"] == 5000.0
        assert values["threads"] == 0 and isinstance(values["threads"], int)  # integer parameters stay integers
    finally:
        node.destroy_node()
        rclpy.shutdown(context=ctx)


BAD_START = [
    ("depth_scale:=deep", "parameter depth_scale: expected a number like 1000.0"),
    ("preset:=nope", "unknown preset 'nope'"),
    ("overrides:=['tracking.iterationz=3']", "unknown config key tracking.iterationz"),
    ("render_rate_hz:=100.0", "parameter render_rate_hz: out of range (allowed: 0.0 to 60.0)"),
    ("downscale:=0.5", "parameter downscale: 0.5 is neither 0 (auto) nor at least 1"),
    ("map_alignment:=sideways", "parameter map_alignment: 'sideways' is not one of"),
    ("camera_mount:=[1.0, 2.0]", "parameter camera_mount: a pose needs 6"),
]


@pytest.mark.parametrize("arg,expected", BAD_START)
def test_bad_start_up_parameters_print_one_line_and_exit_1(arg, expected, capsys):
    assert main(["slam_node", "--ros-args", "-p", arg]) == 1
    err = capsys.readouterr().err
    assert err.splitlines() == [f"slam_node: error: {err.split('error: ', 1)[1].strip()}"] and expected in err, err


def test_the_console_script_prints_no_traceback():
    """The same, as a user runs it: a separate interpreter, nothing but the one line on stderr."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(random.randint(1, 100)), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    env.pop("_ROS_WHEELS_BOOTSTRAP_COMPLETE", None)
    script = str(Path(sys.executable).with_name("slam_node"))
    proc = subprocess.run(
        [script, "--ros-args", "-p", "depth_scale:=deep"],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert proc.returncode == 1
    assert proc.stderr.strip() == ("slam_node: error: parameter depth_scale: expected a number like 1000.0")


def test_threads_sets_torchs_cpu_threads_and_zero_leaves_them():
    before = torch.get_num_threads()
    try:
        use_threads({"threads": 0})
        assert torch.get_num_threads() == before
        use_threads({"threads": 1})
        assert torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(before)
