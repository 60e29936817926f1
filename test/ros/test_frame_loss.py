"""Frames that never reached the node are counted apart from the node's own drops; a busy node gives no
remap advice; /diagnostics states the processing size and the map alignment actually used."""

import dataclasses
import time

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import Log

from sgs_slam_ros.slam_node import build_slam_nodes

from ..polling import wait_for
from .helpers import (
    FAST,
    Feeder,
    Spinner,
    diagnostics_of,
    new_context,
    node_params,
    shut_down,
    tiny_frames,
    watched_slam,
)

pytestmark = pytest.mark.ros
PERIOD = 33_333_333  # ns
OK = 0


def test_frames_lost_before_the_node_are_counted(tiny_scene):
    frames = tiny_frames(tiny_scene)
    watched = watched_slam(node_params(lockstep=False, map_alignment="optical"))
    nodes, feeder, diag, logs = watched.nodes, watched.feeder, watched.diagnostics, watched.logs
    missing = {12, 13, 25, 31}  # the camera's frames that never reach the node
    sent = [k for k in range(40) if k not in missing]
    try:
        assert wait_for(feeder.connected, 10.0)
        for k in sent:  # at a camera's pace: a burst can overflow the subscriptions' queues, a loss of its own
            feeder.publish(dataclasses.replace(frames[k % len(frames)], stamp_ns=(k + 1) * PERIOD))
            time.sleep(PERIOD / 1e9)
        assert wait_for(lambda: nodes[0].assembler.colour_in == len(sent), 10.0)
        assert nodes[0].pipeline.wait_idle(60.0)
        assert nodes[0].pipeline.slam.config.tracking.method == "gauss_newton"  # a live node's tracker

        def settled():  # a status published after the last frame's outcome (once a second)
            d = diagnostics_of(diag, "tracking_node")
            if not d or d[-1][2]["frames_in"] != str(len(sent)) or d[-1][2]["frames_waiting"] != "0":
                return False
            v = d[-1][2]
            return int(v["frames_tracked"]) + int(v["frames_dropped"]) + int(v["frames_rejected"]) == len(sent)

        assert wait_for(settled, 10.0)
        _, _, v = diagnostics_of(diag, "tracking_node")[-1]
        assert v["frames_lost"] == str(len(missing))
        assert all(
            v[f"lost[{t}]"] == str(len(missing)) for t in ("/depth/image", "/semantic/image", "/rgb/camera_info")
        )
        in_ = int(v["frames_in"])  # the node's own accounting covers only what arrived
        assert in_ == int(v["frames_tracked"]) + int(v["frames_dropped"]) + int(v["frames_rejected"])
        lines = [m.msg for m in logs if m.name == "tracking_node" and "never arrived" in m.msg]
        assert lines and "frame(s) of /" in lines[0] and "lost so far" in lines[0]
        assert v["map_alignment"] == "optical" and v["processing_size"] == "64x48" and v["input_size"] == "64x48"
    finally:
        watched.shut_down()


def test_busy_lockstep_node_gives_no_remap_advice(tiny_scene):
    """Frames that take longer than stale_input_s, fed one after the other as bag_player --lockstep does."""
    frames = tiny_frames(tiny_scene)
    ctx = new_context()
    params = node_params(stale_input_s=0.5, map_alignment="floor", overrides=[*FAST, "tracking.method=adam"])
    nodes = build_slam_nodes(context=ctx, parameter_overrides=params)
    # a slow frame (as 640x480 on a small CPU): the worker spends 1.5 s before the pose goes out
    nodes[0].pipeline.pose_listeners.insert(0, lambda *_: time.sleep(1.5))
    feeder = Feeder(ctx)
    diag, logs = [], []
    feeder.create_subscription(DiagnosticArray, "/diagnostics", diag.append, 50)
    feeder.create_subscription(Log, "/rosout", logs.append, 100)
    spinner = Spinner(ctx, [*nodes, feeder])
    try:
        assert wait_for(feeder.connected, 10.0)
        for frame in frames[:4]:
            feeder.publish(frame)
            assert wait_for(lambda f=frame: f.stamp_ns in feeder.poses, 60.0)
        assert nodes[0].pipeline.wait_idle(60.0)
        assert nodes[0].pipeline.slam.config.tracking.method == "adam"  # lockstep keeps the config's (live: GN)
        statuses = diagnostics_of(diag, "tracking_node")
        busy = [m for lvl, m, _ in statuses if m.startswith("busy")]
        assert busy and "frames/s" in busy[0], [m for _, m, _ in statuses]  # slower than stale_input_s: it says so
        assert all(lvl == OK for lvl, _, _ in statuses), statuses
        assert not [m.msg for m in logs if "silent" in m.msg and "remap" in m.msg]
        # the tiny scene's first frame sees no floor: the log and /diagnostics agree on the fallback
        alignment = statuses[-1][2]["map_alignment"]
        fallback = [m.msg for m in logs if "no floor plane" in m.msg]
        assert alignment.startswith("mount") if fallback else alignment == "floor"
    finally:
        shut_down(ctx, [*nodes, feeder], spinner)
