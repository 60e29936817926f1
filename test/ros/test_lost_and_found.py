"""A kidnapped camera through slam_node: lost and found again in the log and /diagnostics, /tf held while lost."""

import dataclasses

import pytest

from ..polling import wait_for
from ..slam.views import room_frame
from .helpers import FAST, diagnostics_of, node_params, watched_slam

pytestmark = pytest.mark.ros
PERIOD = 33_333_333  # ns
WARN = 1


def test_a_kidnapped_camera_is_reported_lost_and_relocalized():
    # the orbit 3 degrees a frame to 57 degrees, then carried back unseen to 3 degrees
    order = [*range(0, 40, 2), *range(2, 16, 2)]
    params = node_params(map_alignment="optical", overrides=[*FAST, "keyframes.every=3", "guard.lost_after=2"])
    watched = watched_slam(params)
    nodes, feeder, diag, logs = watched.nodes, watched.feeder, watched.diagnostics, watched.logs
    states = []
    nodes[0].pipeline.pose_listeners.append(lambda _frame, outcome: states.append(outcome.state))
    try:
        assert wait_for(feeder.connected, 10.0)
        for n, i in enumerate(order):
            frame = room_frame(i)
            stamped = dataclasses.replace(frame, stamp_ns=(n + 1) * PERIOD, gt_c2w=None, index=n)
            feeder.publish(stamped)
            assert wait_for(lambda s=stamped.stamp_ns: s in feeder.poses, 60.0)  # lockstep: one pose a frame
            assert wait_for(lambda k=n: len(states) > k, 5.0)
            if states and states[-1] == "lost":
                assert wait_for(lambda: any(d[0] == WARN for d in diagnostics_of(diag, "tracking_node")), 5.0)
        assert "lost" in states and states.index("lost") <= 22 and "relocalized" in states
        assert states[-1] == "ok"

        def settled():
            d = diagnostics_of(diag, "tracking_node")
            return d and d[-1][2]["frames_tracked"] == str(len(order))

        assert wait_for(settled, 10.0)
        _level, _message, values = diagnostics_of(diag, "tracking_node")[-1]
        assert values["tracking_state"] == "ok" and values["relocalizations"] == "1"
        assert values["tracking_lost_events"] == "1" and values["frames_while_lost"] == str(states.count("lost"))
        lost_status = [d for d in diagnostics_of(diag, "tracking_node") if d[2]["tracking_state"] == "lost"]
        assert lost_status and all(d[0] == WARN and "lost" in d[1] for d in lost_status)
        lines = [m.msg for m in logs if m.name == "tracking_node"]
        assert any(line.startswith("camera lost") for line in lines)
        assert any(line.startswith("relocalized") for line in lines)
        assert len(nodes[0].path) == len(order) - states.count("lost")  # no held pose joins the path
    finally:
        watched.shut_down()
