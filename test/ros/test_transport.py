"""Two processes, 30 Hz, 640x480: every frame bag_player sends reaches slam_node or is counted as lost."""

import dataclasses
import os
import random
import signal
import subprocess
import sys

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node

from bags import convert
from sgs_slam_core.datasets import open_dataset
from sgs_slam_core.datasets.base import resize_frame
from sgs_slam_ros import transport
from sgs_slam_ros.transport import (
    PROFILE_ENV,
    apply_transport,
    profile_path,
    profile_socket_buffers,
    socket_buffer_advice,
)

from ..polling import wait_for
from .helpers import FAST, Spinner, diagnostics_of, new_context

pytestmark = pytest.mark.ros
FRAMES, MARKERS, PERIOD = 60, 5, 33_333_333  # 2 s at 30 Hz, then a few frames that close the stream


class CameraSized:
    """The tiny scene's frames at 640x480 and 30 Hz stamps (the Dataset protocol, for the converter).

    ``count`` frames whose stamps go on from frame ``first`` of the stream.
    """

    def __init__(self, scene, count: int = FRAMES, first: int = 0) -> None:
        self.base = open_dataset(scene)
        self.count, self.first = count, first
        self.name, self.label_table = "tiny640", self.base.label_table
        self.has_labels, self.has_ground_truth = True, False

    def __len__(self) -> int:
        return self.count

    def __getitem__(self, i: int):
        f = self.base[i % len(self.base)]
        k = f.intrinsics.scaled(10.0)
        rgb, depth, labels = resize_frame(f.rgb, f.depth, f.labels, k.width, k.height)
        n = self.first + i
        return dataclasses.replace(
            f, rgb=rgb, depth=depth, labels=labels, intrinsics=k, stamp_ns=(n + 1) * PERIOD, gt_c2w=None, index=n
        )


def child_env(domain: int) -> dict[str, str]:
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    env.pop("_ROS_WHEELS_BOOTSTRAP_COMPLETE", None)  # let the child set up its own library path
    env.pop(PROFILE_ENV, None)
    return env


def test_apply_transport_keeps_a_users_profile(monkeypatch):
    monkeypatch.delenv(PROFILE_ENV, raising=False)
    assert "shared memory" in apply_transport("shm") and os.environ[PROFILE_ENV] == str(profile_path())
    monkeypatch.setenv(PROFILE_ENV, "/my/profile.xml")
    assert "/my/profile.xml" in apply_transport("shm") and os.environ[PROFILE_ENV] == "/my/profile.xml"
    monkeypatch.setenv("RMW_IMPLEMENTATION", "rmw_cyclonedds_cpp")
    assert "cyclonedds" in apply_transport("shm")
    with pytest.raises(ValueError, match="transport must be one of"):
        apply_transport("carrier-pigeon")


def node_arguments(overrides: str) -> list[str]:
    """``--ros-args`` of a slam_node on a RealSense driver's topic names, with the given config overrides."""
    remaps = {
        "rgb/image": "color/image_raw",
        "depth/image": "depth/image_raw",
        "semantic/image": "semantic/image_raw",
        "rgb/camera_info": "color/camera_info",
    }
    params = ["preset:=synthetic", f"overrides:={overrides}", "downscale:=10.0", "map_alignment:=optical"]
    return [
        "--ros-args",
        *(a for p in params for a in ("-p", p)),
        *(a for name, topic in remaps.items() for a in ("-r", f"{name}:=/camera/{topic}")),
    ]


def test_bag_player_to_slam_node_every_frame_arrives_or_is_counted(tiny_scene, tmp_path):
    bag = tmp_path / "cam640"
    convert(CameraSized(tiny_scene), bag, compress=False)
    domain = random.randint(1, 100)
    overrides = "[" + ",".join(f"'{o}'" for o in FAST) + "]"
    node = subprocess.Popen(
        [sys.executable, "-m", "sgs_slam_ros.slam_node", *node_arguments(overrides)],
        env=child_env(domain),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    markers = tmp_path / "markers"
    convert(CameraSized(tiny_scene, MARKERS, first=FRAMES), markers, compress=False)
    ctx = new_context(domain)
    probe = Node("probe", context=ctx)
    diag = []
    probe.create_subscription(DiagnosticArray, "/diagnostics", diag.append, 50)
    spinner = Spinner(ctx, [probe])
    try:
        for source, frames in ((bag, FRAMES), (markers, MARKERS)):
            play = [sys.executable, "-m", "sgs_slam_ros.bag_player", str(source), "--wait", "120"]
            player = subprocess.run(
                play, check=False, env=child_env(domain), capture_output=True, text=True, timeout=240
            )
            assert player.returncode == 0, player.stderr
            assert f"done: {frames} frames" in player.stderr and "Fast DDS shared memory" in player.stderr, (
                player.stderr
            )

        def counted():
            d = diagnostics_of(diag, "tracking_node")
            return None if not d else int(d[-1][2]["frames_in"]) + int(d[-1][2]["frames_lost"])

        # A frame lost after the last one that arrived shows as a gap only when a later frame comes:
        # marker frames after the bag's end, from a second player (same transport), close the stream;
        # a lost marker is a counted gap as well, but for the last one, which no later frame shows.
        assert wait_for(lambda: (counted() or 0) >= FRAMES + MARKERS - 1, 20.0), diagnostics_of(diag, "tracking_node")
        values = diagnostics_of(diag, "tracking_node")[-1][2]
        print(f"frames_in {values['frames_in']} frames_lost {values['frames_lost']} of {FRAMES + MARKERS}")
    finally:
        spinner.stop()
        probe.destroy_node()
        ctx.try_shutdown()
        node.send_signal(signal.SIGINT)
        try:
            node.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            node.kill()
            node.communicate()


def fake_host(tmp_path, rmem: int, wmem: int):
    proc = tmp_path / "net_core"
    proc.mkdir(exist_ok=True)
    (proc / "rmem_max").write_text(f"{rmem}\n")
    (proc / "wmem_max").write_text(f"{wmem}\n")
    return proc


def test_the_shipped_profile_asks_for_socket_buffers_a_frame_fits_in_and_a_short_host_gets_the_sysctl(tmp_path):
    shipped = profile_path()
    assert profile_socket_buffers(shipped) == {"receiveBufferSize": 4194304, "sendBufferSize": 4194304}
    advice = socket_buffer_advice(shipped, fake_host(tmp_path, 212992, 212992))  # a stock Linux host
    assert advice is not None and "\n" not in advice
    assert (
        "rmem_max 212992" in advice and "sudo sysctl -w net.core.rmem_max=4194304 net.core.wmem_max=4194304" in advice
    )
    assert socket_buffer_advice(shipped, fake_host(tmp_path, 8388608, 4194304)) is None
    assert socket_buffer_advice(None, fake_host(tmp_path, 1, 1)) is None  # no profile: DDS's own defaults
    plain = tmp_path / "plain.xml"
    plain.write_text("<profiles><participant profile_name='p'/></profiles>")
    assert socket_buffer_advice(plain, fake_host(tmp_path, 1, 1)) is None  # no buffer sizes asked for
    assert socket_buffer_advice(shipped, tmp_path / "absent") is None  # not Linux: nothing to compare


@pytest.mark.ros
def test_a_host_short_of_socket_buffers_is_told_once_and_diagnostics_say_so(tmp_path, monkeypatch, capfd):
    from .helpers import node_params, watched_slam

    monkeypatch.setenv(PROFILE_ENV, str(profile_path()))
    monkeypatch.setattr(transport, "PROC_NET_CORE", fake_host(tmp_path, 212992, 212992))
    slam = watched_slam(node_params())
    try:

        def reported() -> bool:
            found = diagnostics_of(slam.diagnostics, "tracking_node")
            return bool(found) and "socket_buffers" in found[-1][2]

        assert wait_for(reported, 10.0)
        assert diagnostics_of(slam.diagnostics, "tracking_node")[-1][2]["socket_buffers"].startswith("too small")
    finally:
        slam.shut_down()
    told = [line for line in capfd.readouterr().err.splitlines() if "sysctl" in line]  # logged while the node starts
    assert len(told) == 1 and "[tracking_node]" in told[0] and "net.core.rmem_max=4194304" in told[0]
