"""bag_player into slam_node: live counts that add up, and a second lockstep replay after --reset."""

import os
import subprocess
import sys

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from sensor_msgs.msg import Image

from bags.writer import convert
from msg_adapters import stamp_to_ns
from sgs_slam_core.datasets import open_dataset
from sgs_slam_ros.bag_player import RESET_SERVICES, BagPlayer
from sgs_slam_ros.slam_node import build_slam_nodes

from ..polling import wait_for
from .helpers import Spinner, diagnostics_of, new_context, node_params, shut_down

pytestmark = pytest.mark.ros

REMAPS = [
    "--ros-args",
    *("-r", "rgb/image:=/camera/color/image_raw", "-r", "depth/image:=/camera/depth/image_raw"),
    *("-r", "semantic/image:=/camera/semantic/image_raw", "-r", "rgb/camera_info:=/camera/color/camera_info"),
]


@pytest.fixture(scope="module")
def tiny_bag(tiny_scene, tmp_path_factory):
    bag = tmp_path_factory.mktemp("bags") / "tiny"
    convert(open_dataset(tiny_scene), bag)
    return bag


def start(ctx, **params):
    return build_slam_nodes(context=ctx, parameter_overrides=node_params(**params), cli_args=REMAPS)


def stop(spinner, ctx, nodes):
    shut_down(ctx, nodes, spinner)


def test_live_replay_counts_add_up_in_diagnostics(tiny_bag):
    ctx = new_context()
    nodes = start(ctx, lockstep=False, input_qos="reliable")
    tracking, mapping = nodes
    player = BagPlayer(tiny_bag, rate=3.0, context=ctx)  # 12 frames in 0.12 s: faster than tracking keeps up
    diag = []
    player.create_subscription(DiagnosticArray, "/diagnostics", diag.append, 50)
    spinner = Spinner(ctx, [*nodes, player])
    try:
        assert player.wait_for_subscribers(20.0)
        assert player.play().frames == 12
        assert wait_for(lambda: tracking.assembler.colour_in == 12, 10.0)
        assert mapping.pipeline.wait_idle(60.0)
        st = mapping.pipeline.stats

        def settled():  # the newest diagnostics of both nodes report the idle pipeline
            t, m = diagnostics_of(diag, "tracking_node"), diagnostics_of(diag, "mapping_node")
            return (
                t
                and m
                and t[-1][2]["frames_tracked"] == str(st.tracked)
                and m[-1][2]["frames_mapped"] == str(st.mapped)
            )

        assert wait_for(settled, 10.0)
        t = {k: int(v) for k, v in diagnostics_of(diag, "tracking_node")[-1][2].items() if k.startswith("frames_")}
        m = diagnostics_of(diag, "mapping_node")[-1][2]
        assert t["frames_in"] == 12 and t["frames_rejected"] == 0 and t["frames_waiting"] == 0
        assert t["frames_in"] == t["frames_tracked"] + t["frames_dropped"], t
        assert t["frames_dropped"] >= 1, t  # live mode keeps up by dropping
        assert st.errors == 0
        assert t["frames_tracked"] == int(m["frames_mapped"]) + int(m["jobs_dropped"]), (t, m)
        assert m["mapping_steps_per_frame"] == f"{st.map_steps_per_frame:.1f}"  # as /diagnostics rounds it
        assert st.map_steps_per_frame >= 1
    finally:
        stop(spinner, ctx, [*nodes, player])


def test_preload_holds_the_first_messages_of_the_budget_and_play_publishes_them_all(tiny_bag):
    ctx = new_context()
    whole = BagPlayer(tiny_bag, preload_mb=1024.0, context=ctx)
    sizes = [ref.length for _, _, ref in whole._messages()]
    budget = sum(sizes[:5]) + sizes[5] // 2  # room for five messages and half of the sixth
    part = BagPlayer(tiny_bag, preload_mb=budget / 2**20, rate=4.0, context=ctx)
    none = BagPlayer(tiny_bag, context=ctx)
    received = []
    part.create_subscription(Image, "/camera/color/image_raw", received.append, 50)
    spinner = Spinner(ctx, [part])
    try:
        assert whole.preload() == whole.message_count == len(sizes)
        assert part.preload() == 5 and none.preload() == 0
        assert all(whole._payload(i, ref) == whole._index.payload(ref) for i, _, ref in whole._messages())
        stats = part.play()
        assert (stats.frames, stats.messages, stats.preloaded) == (12, len(sizes), 5)
        assert wait_for(lambda: len(received) == 12, 10.0)  # the preloaded colour frames arrive like the rest
    finally:
        shut_down(ctx, [whole, part, none], spinner)
    ctx = new_context()
    try:
        with pytest.raises(ValueError, match="preload_mb"):
            BagPlayer(tiny_bag, preload_mb=-1.0, context=ctx)
    finally:
        ctx.try_shutdown()


def test_second_lockstep_replay_after_reset(tiny_bag):
    """The second replay's stamps start again: without a reset every frame would be refused."""
    ctx = new_context()
    nodes = start(ctx, lockstep=True, input_qos="reliable_all")
    tracking, mapping = nodes
    player = BagPlayer(tiny_bag, lockstep=True, lockstep_timeout_s=60.0, context=ctx)
    poses = []
    player.create_subscription(PoseStamped, "/tracking_node/pose", poses.append, 50)
    spinner = Spinner(ctx, [*nodes, player])
    try:
        assert player.wait_for_subscribers(20.0)
        assert player.play().lockstep_timeouts == 0
        assert wait_for(lambda: len(poses) == 12, 10.0)
        first = [stamp_to_ns(p.header.stamp) for p in poses]
        # the second replay from another process, as a user runs it: bag_player BAG --lockstep --reset
        env = dict(os.environ, ROS_DOMAIN_ID=str(ctx.get_domain_id()), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
        env.pop("_ROS_WHEELS_BOOTSTRAP_COMPLETE", None)
        cmd = [
            sys.executable,
            "-m",
            "sgs_slam_ros.bag_player",
            str(tiny_bag),
            "--lockstep",
            "--reset",
            "--timeout",
            "60",
        ]
        proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300, check=False)
        assert proc.returncode == 0, proc.stderr
        assert f"reset {', '.join(RESET_SERVICES)} before playing" in proc.stderr
        assert "done: 12 frames" in proc.stderr and "0 timeouts" in proc.stderr, proc.stderr
        assert "preloaded" in proc.stderr, proc.stderr  # the tiny bag fits the default budget
        assert "terminate called" not in proc.stderr
        assert wait_for(lambda: len(poses) == 24, 10.0)
        assert [stamp_to_ns(p.header.stamp) for p in poses[12:]] == first  # every frame again, in order
        assert sum(tracking.assembler.rejected.values()) == 0
        assert mapping.pipeline.wait_idle(30.0) and mapping.pipeline.stats.mapped == 24
        assert len(mapping.pipeline.slam.trajectory) == 12  # a fresh map, not the first run continued
    finally:
        stop(spinner, ctx, [*nodes, player])
