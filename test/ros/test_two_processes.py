"""tracking_node and mapping_node as two OS processes talking over DDS (loopback only)."""

import os
import random
import signal
import subprocess
import sys
import threading
import time

import pytest
from sensor_msgs.msg import PointCloud2

from bags import convert
from sgs_slam_core.datasets import open_dataset

from ..polling import wait_for
from .helpers import FAST, Feeder, Spinner, new_context

pytestmark = pytest.mark.ros


def start(module: str, domain: int, *params: str, overrides: list[str] = FAST) -> subprocess.Popen:
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    env.pop("_ROS_WHEELS_BOOTSTRAP_COMPLETE", None)  # let the child set up its own library path
    overrides = "[" + ",".join(f"'{o}'" for o in overrides) + "]"
    args = [
        "-p",
        "preset:=synthetic",
        "-p",
        f"overrides:={overrides}",
        "-p",
        "lockstep:=true",
        "-p",
        "input_qos:=reliable_all",
        *(a for p in params for a in ("-p", p)),
    ]
    return subprocess.Popen(
        [sys.executable, "-m", module, "--ros-args", *args],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )


def test_poses_arrive_across_processes(tiny_scene):
    frames = [open_dataset(tiny_scene)[i] for i in range(5)]
    domain = random.randint(1, 100)
    mapper = start("sgs_slam_ros.mapping_node", domain, "pose_source:=topic", "gaussians_rate_hz:=0.0")
    tracker = start("sgs_slam_ros.tracking_node", domain, "map_source:=topic")
    ctx = new_context(domain)
    feeder = Feeder(ctx)
    maps = []
    map_sub = feeder.create_subscription(PointCloud2, "/mapping_node/gaussians", maps.append, 10)
    spinner = Spinner(ctx, [feeder])
    try:
        assert wait_for(lambda: feeder.connected(subscribers=2) and map_sub.get_publisher_count() >= 1, 60.0), (
            "the two nodes did not subscribe"
        )  # two interpreters start; every topic the test reads or writes is matched before frame 0
        for f in frames:
            feeder.publish(f)
            assert wait_for(lambda f=f: f.stamp_ns in feeder.poses, 60.0), f"no pose for frame {f.index}"
        assert wait_for(lambda: maps, 30.0)  # the mapper published its map for the tracker
        assert len(feeder.poses) == len(frames)
    finally:
        spinner.stop()
        feeder.destroy_node()
        ctx.try_shutdown()
        outputs = []
        for proc in (tracker, mapper):
            proc.send_signal(signal.SIGINT)
            try:
                outputs.append(proc.communicate(timeout=20)[0])
            except subprocess.TimeoutExpired:
                proc.kill()
                outputs.append(proc.communicate()[0])
        print("\n---- node logs ----\n" + "\n".join(outputs))  # pytest shows it when the test fails
    assert tracker.returncode == 0 and mapper.returncode == 0, "\n".join(outputs)


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_while_mapping_runs_exits_cleanly(tiny_scene, signum):
    """The signal lands while the mapping worker is busy: the worker stops first, exit code 0."""
    frame = open_dataset(tiny_scene)[0]
    domain = random.randint(1, 100)
    node = start("sgs_slam_ros.slam_node", domain, overrides=["tracking.adam.iterations=15", "mapping.iterations=3000"])
    ctx = new_context(domain)
    feeder = Feeder(ctx)
    spinner = Spinner(ctx, [feeder])
    try:
        assert wait_for(feeder.connected, 60.0), "slam_node did not subscribe"
        feeder.publish(frame)
        assert wait_for(lambda: frame.stamp_ns in feeder.poses, 60.0), "no pose for frame 0"
        node.send_signal(signum)  # frame 0's pose is out; its 3000 mapping iterations are running
        try:
            output = node.communicate(timeout=30)[0]
        except subprocess.TimeoutExpired:
            node.kill()
            output = node.communicate()[0]
            pytest.fail("slam_node did not stop within 30 s of the signal:\n" + output)
    finally:
        spinner.stop()
        feeder.destroy_node()
        ctx.try_shutdown()
    assert node.returncode == 0, output
    assert "Traceback" not in output, output


def test_bag_player_stops_on_a_signal_mid_play(tiny_scene, tmp_path):
    """Ctrl-C while it publishes: play stops first, then the context goes (was: an RCLError traceback)."""
    bag = tmp_path / "bag"
    convert(open_dataset(tiny_scene), bag)
    env = dict(os.environ, ROS_DOMAIN_ID=str(random.randint(1, 100)), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    env.pop("_ROS_WHEELS_BOOTSTRAP_COMPLETE", None)
    command = [sys.executable, "-m", "sgs_slam_ros.bag_player", str(bag), "--loop", "--wait", "0", "--rate", "20"]
    proc = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(proc.stdout), daemon=True)  # one line at a time
    reader.start()
    try:
        assert wait_for(lambda: any("playing anyway" in line for line in lines) or proc.poll() is not None, 60.0)
        time.sleep(2.0)  # looping at 20x: publishing all the time
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        reader.join(10.0)
    output = "".join(lines)
    assert proc.returncode == 0, output
    assert "Traceback" not in output and "stopped:" in output, output
