"""The executors the nodes can spin on: both serve topics, timers and services."""

import threading

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from std_srvs.srv import Trigger

from sgs_slam_ros.runtime import EXECUTORS, POLL_S, make_executor
from sgs_slam_ros.slam_node import build_slam_nodes

from ..polling import wait_for
from .helpers import Feeder, new_context, node_params, shut_down, tiny_frames

pytestmark = pytest.mark.ros


@pytest.mark.parametrize("name", EXECUTORS)
def test_each_executor_serves_frames_timers_and_services(tiny_scene, name):
    frames = tiny_frames(tiny_scene)[:3]
    ctx = new_context()
    nodes = build_slam_nodes(context=ctx, parameter_overrides=node_params())
    feeder = Feeder(ctx)
    diagnostics = []
    feeder.create_subscription(DiagnosticArray, "/diagnostics", diagnostics.append, 10)
    executor = make_executor(name, ctx)
    for node in [*nodes, feeder]:
        executor.add_node(node)
    stop = threading.Event()

    def spin():  # as run_nodes does
        while not stop.is_set():
            executor.spin_once(timeout_sec=POLL_S)

    thread = threading.Thread(target=spin, daemon=True)
    thread.start()
    try:
        assert wait_for(feeder.connected, 10.0), "slam_node did not subscribe"
        for f in frames:  # subscriptions and the tracking thread's publisher
            feeder.publish(f)
            assert wait_for(lambda f=f: f.stamp_ns in feeder.poses, 60.0), f"no pose for frame {f.index}"
        assert wait_for(lambda: diagnostics, 5.0)  # a steady-clock timer
        client = feeder.create_client(Trigger, "/tracking_node/reset")
        assert client.wait_for_service(timeout_sec=10.0)
        future = client.call_async(Trigger.Request())
        assert wait_for(future.done, 30.0) and future.result().success
        assert nodes[0].pipeline.snapshot().frames_processed == 0  # the reset reached the SLAM
    finally:
        stop.set()
        thread.join(10.0)
        executor.shutdown()
        shut_down(ctx, [*nodes, feeder])


def test_an_unknown_executor_is_refused():
    with pytest.raises(ValueError, match="executor must be one of events, single"):
        make_executor("threads")
