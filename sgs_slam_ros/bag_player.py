"""``bag_player``: replay an MCAP bag into ROS topics (ros2 bag play is not on PyPI).

Publishes every topic's raw CDR payloads (no re-serialisation) with the QoS recorded in the bag
(reliable by default) and ``/clock`` from the bag (or from log times with ``--clock``). Options: a
rate factor, ``--loop``, a start offset, ``--lockstep``, which waits for the SLAM pose of each
colour frame (by header stamp) before publishing the next one, so a replay drops nothing and is
deterministic, and ``--reset``, which calls the SLAM nodes' ``~/reset`` first (a second replay's
stamps would otherwise go backwards and every frame be refused). As a camera hands over its images
ready, the first ``--preload-mb`` MiB of payloads are read and decompressed before the clock starts,
so reading the bag does not take the machine from the nodes during the replay::

    bag_player scene0000_00_bag --lockstep --reset --ros-args -r __ns:=/
"""

from __future__ import annotations

import argparse
import importlib
import sys
import threading
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import rclpy
from geometry_msgs.msg import PoseStamped
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import remove_ros_args
from rosgraph_msgs.msg import Clock
from std_srvs.srv import Trigger

from bags.errors import BagError
from bags.layout import BagTopics
from bags.mcap_index import MessageRef
from bags.reader import bag_file, open_index, read_metadata
from msg_adapters import stamp_to_ns
from sgs_slam_ros.runtime import stop_on_signals
from sgs_slam_ros.transport import TRANSPORTS, apply_transport

__all__ = ["RESET_SERVICES", "BagPlayer", "PlayStats", "main"]

RESET_SERVICES = ("/tracking_node/reset", "/mapping_node/reset")
_SETTLE_S = 0.5  # after the subscribers appear: time for their side of the match (see wait_for_subscribers)


@dataclass
class PlayStats:
    """What a replay did."""

    messages: int = 0
    frames: int = 0
    poses_received: int = 0
    lockstep_timeouts: int = 0
    preloaded: int = 0  # messages read before the clock started


def _message_class(type_name: str) -> type:
    pkg, kind, name = type_name.split("/")
    return getattr(importlib.import_module(f"{pkg}.{kind}"), name)


def _recorded_qos(bag: Path) -> dict[str, QoSProfile]:
    """Offered QoS per topic from a rosbag2 metadata.yaml (reliable / volatile when unknown)."""
    out: dict[str, QoSProfile] = {}
    for entry in read_metadata(bag).get("topics_with_message_count", []):
        meta_topic = entry.get("topic_metadata", {})
        profiles = meta_topic.get("offered_qos_profiles") or []
        profile = profiles[0] if isinstance(profiles, list) and profiles else {}
        reliability = str(profile.get("reliability", "reliable")).lower() if isinstance(profile, dict) else "reliable"
        durability = str(profile.get("durability", "volatile")).lower() if isinstance(profile, dict) else "volatile"
        out[meta_topic.get("name", "")] = QoSProfile(
            depth=100,
            history=HistoryPolicy.KEEP_LAST,
            reliability=ReliabilityPolicy.BEST_EFFORT if "best" in reliability else ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL if "transient" in durability else DurabilityPolicy.VOLATILE,
        )
    return out


class BagPlayer(Node):
    """Publishes a bag's messages; :meth:`play` runs the replay (call it outside the executor)."""

    def __init__(
        self,
        bag: str | Path,
        rate: float = 1.0,
        loop: bool = False,
        start_offset_s: float = 0.0,
        lockstep: bool = False,
        pose_topic: str = "/tracking_node/pose",
        lockstep_timeout_s: float = 60.0,
        clock: bool = False,
        topics: BagTopics = BagTopics(),  # noqa: B008 - immutable default
        preload_mb: float = 0.0,
        **kwargs: Any,
    ) -> None:
        super().__init__("bag_player", **kwargs)
        if not rate > 0:
            raise ValueError(f"rate must be > 0, got {rate}")
        if not preload_mb >= 0:
            raise ValueError(f"preload_mb must be >= 0, got {preload_mb}")
        self.preload_bytes = round(preload_mb * 2**20)
        self._preloaded: dict[int, bytes] | None = None  # position in the play order -> payload
        self.file = bag_file(Path(bag))
        self.rate, self.loop, self.start_offset_ns = rate, loop, round(start_offset_s * 1e9)
        self.lockstep, self.lockstep_timeout_s, self.synth_clock = lockstep, lockstep_timeout_s, clock
        self.topics = topics
        self.stats = PlayStats()
        self._stop = threading.Event()
        self._poses: set[int] = set()
        self._pose_cv = threading.Condition()
        qos = _recorded_qos(Path(bag))
        self._pubs: dict[str, Any] = {}
        self._index = open_index(self.file)
        self._order = sorted(self._index.messages, key=lambda m: m.log_time)  # stable: file order breaks ties
        self._topic = {cid: ch.topic for cid, ch in self._index.channels.items()}
        for channel in self._index.channels.values():
            if channel.schema is None:
                raise BagError(f"{self.file}: {channel.topic} has no schema; cannot publish it")
            profile = qos.get(channel.topic, QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
            msg_class = _message_class(channel.schema.name)
            self._pubs[channel.topic] = self.create_publisher(msg_class, channel.topic, profile)
        self._clock_pub = self.create_publisher(Clock, "/clock", 10) if clock and "/clock" not in self._pubs else None
        if lockstep:
            self.create_subscription(PoseStamped, pose_topic, self._on_pose, 100)
        self.get_logger().info(f"playing {self.file} ({len(self._pubs)} topics{', lockstep' if lockstep else ''})")

    @property
    def message_count(self) -> int:
        """Messages in the bag (every topic)."""
        return len(self._order)

    def _on_pose(self, msg: PoseStamped) -> None:
        with self._pose_cv:
            self._poses.add(stamp_to_ns(msg.header.stamp))
            self.stats.poses_received += 1
            self._pose_cv.notify_all()

    def destroy_node(self) -> None:
        """Close the bag, then destroy the node."""
        self._index.close()
        super().destroy_node()

    def stop(self) -> None:
        """Make :meth:`play` return soon."""
        self._stop.set()
        with self._pose_cv:
            self._pose_cv.notify_all()

    def wait_for_subscribers(self, timeout_s: float = 10.0) -> bool:
        """Block until the colour, depth and camera_info topics have subscribers (nothing is published into the void).

        DDS discovery between processes takes up to a second or two: a short bag played at once is lost.
        Once this side sees the subscribers it waits ``_SETTLE_S`` more: the subscriber's side of the
        match can lag (across hosts, measured: the first two frames of a short bag dropped).
        """
        end = time.monotonic() + timeout_s
        wanted = (self.topics.color, self.topics.depth, self.topics.camera_info)
        pubs = [self._pubs[t] for t in wanted if t in self._pubs]
        while any(p.get_subscription_count() == 0 for p in pubs):
            if time.monotonic() > end or self._stop.is_set():
                return False
            time.sleep(0.05)
        self._stop.wait(_SETTLE_S)  # ends early when the player is stopped
        return True

    def reset_slam(self, services: Sequence[str] = RESET_SERVICES, timeout_s: float = 30.0) -> list[str]:
        """Call each Trigger service that exists (needs a spinning executor); returns the ones that succeeded."""
        done = []
        for name in services:
            client = self.create_client(Trigger, name)
            try:
                if not client.wait_for_service(timeout_sec=min(timeout_s, 5.0)):
                    self.get_logger().warn(f"--reset: no service {name}")
                    continue
                future = client.call_async(Trigger.Request())
                end = time.monotonic() + timeout_s
                while not future.done() and time.monotonic() < end and not self._stop.is_set():
                    time.sleep(0.02)
                result = future.result() if future.done() else None
                if result is not None and result.success:
                    done.append(name)
                else:
                    self.get_logger().warn(f"--reset: {name} failed: {result.message if result else 'no answer'}")
            finally:
                self.destroy_client(client)
        return done

    def _messages(self) -> Iterator[tuple[int, str, MessageRef]]:
        """(position in the play order, topic, message) from the start offset on."""
        start = self._order[0].log_time if self._order else 0
        for position, ref in enumerate(self._order):
            if ref.log_time - start >= self.start_offset_ns:
                yield position, self._topic[ref.channel_id], ref

    def preload(self) -> int:
        """Read the payloads of the first ``preload_mb`` MiB of the replay into memory; how many (once)."""
        if self._preloaded is None:
            self._preloaded, held = {}, 0
            for position, _, ref in self._messages():
                if held + ref.length > self.preload_bytes or self._stop.is_set():
                    break
                self._preloaded[position] = self._index.payload(ref)
                held += ref.length
            self.stats.preloaded = len(self._preloaded)
        return len(self._preloaded)

    def _payload(self, position: int, ref: MessageRef) -> bytes:
        preloaded = self._preloaded.get(position) if self._preloaded is not None else None
        return self._index.payload(ref) if preloaded is None else preloaded

    def play(self) -> PlayStats:
        """Replay once (or until stopped with ``loop``); returns counters. Preloads first (see :meth:`preload`)."""
        self.preload()
        while True:
            self._play_once()
            if not self.loop or self._stop.is_set():
                return self.stats

    def _play_once(self) -> None:
        wall0 = bag0 = None
        pending_frame: int | None = None  # lockstep: the colour frame whose pose we still wait for
        for position, topic, ref in self._messages():
            log_time = ref.log_time
            if self._stop.is_set():
                return
            if pending_frame is not None and topic == self.topics.color:  # wait before the next frame starts
                self._wait_pose(pending_frame)
                pending_frame = None
            if not self.lockstep:
                wall0, bag0 = (time.monotonic(), log_time) if wall0 is None else (wall0, bag0)
                delay = (log_time - bag0) / 1e9 / self.rate - (time.monotonic() - wall0)
                if delay > 0 and self._stop.wait(delay):
                    return
            if self._clock_pub is not None:
                self._clock_pub.publish(Clock(clock=rclpy.time.Time(nanoseconds=log_time).to_msg()))
            self._pubs[topic].publish(self._payload(position, ref))
            self.stats.messages += 1
            if topic == self.topics.color:
                self.stats.frames += 1
                if self.lockstep:
                    pending_frame = ref.stamp_ns  # None (no header): nothing to wait for
        if pending_frame is not None:
            self._wait_pose(pending_frame)

    def _wait_pose(self, stamp_ns: int) -> None:
        with self._pose_cv:
            ok = self._pose_cv.wait_for(lambda: stamp_ns in self._poses or self._stop.is_set(), self.lockstep_timeout_s)
        if not ok:
            self.stats.lockstep_timeouts += 1
            self.get_logger().warn(
                f"no pose for the frame at {stamp_ns} ns within {self.lockstep_timeout_s} s; going on"
            )


def _parse(argv: Sequence[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="bag_player", description=__doc__.splitlines()[0])
    p.add_argument("bag", type=Path, help="rosbag2 folder or .mcap file")
    p.add_argument("--rate", type=float, default=1.0, help="playback speed factor")
    p.add_argument("--loop", action="store_true", help="start again at the end")
    p.add_argument("--start", type=float, default=0.0, help="skip the first S seconds")
    p.add_argument("--lockstep", action="store_true", help="wait for the SLAM pose of each frame")
    p.add_argument("--pose-topic", default="/tracking_node/pose", help="pose topic for --lockstep")
    p.add_argument("--timeout", type=float, default=60.0, help="seconds to wait for a pose in --lockstep")
    p.add_argument("--clock", action="store_true", help="publish /clock from log times (if the bag has none)")
    p.add_argument("--wait", type=float, default=30.0, help="seconds to wait for subscribers before playing")
    p.add_argument(
        "--preload-mb",
        type=float,
        default=1024.0,
        help="MiB of messages read and decompressed before the clock starts (0 = read each when it is due)",
    )
    p.add_argument(
        "--reset", action="store_true", help=f"call the SLAM's reset services first ({', '.join(RESET_SERVICES)})"
    )
    p.add_argument("--reset-service", action="append", metavar="NAME", help="reset this Trigger service instead")
    p.add_argument(
        "--transport",
        choices=TRANSPORTS,
        default="shm",
        help="shm: Fast DDS shared memory with segments for whole frames (config/fastdds_shm.xml; a profile "
        "named by FASTRTPS_DEFAULT_PROFILES_FILE is kept); default: Fast DDS's built-in transports",
    )
    return p.parse_args(argv)


def _player(opts: argparse.Namespace) -> BagPlayer:
    """The player the command line describes."""
    return BagPlayer(
        opts.bag,
        opts.rate,
        opts.loop,
        opts.start,
        opts.lockstep,
        opts.pose_topic,
        opts.timeout,
        opts.clock,
        preload_mb=opts.preload_mb,
    )


def main(args: list[str] | None = None) -> int:
    """Entry point of ``bag_player``; Ctrl-C stops cleanly."""
    argv = list(sys.argv if args is None else args)
    opts = _parse(remove_ros_args(argv)[1:])
    transport = apply_transport(opts.transport)  # before rclpy.init: Fast DDS reads it with the first participant
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)  # Ctrl-C stops play before the context
    executor = MultiThreadedExecutor(num_threads=2)
    player: BagPlayer | None = None
    spinner = None
    stopped = threading.Event()

    def on_signal() -> None:
        stopped.set()
        if player is not None:
            player.stop()

    with stop_on_signals(on_signal):
        try:
            player = _player(opts)
            if stopped.is_set():  # the signal came while the bag was being indexed
                return 0
            player.get_logger().info(f"transport: {transport}")
            executor.add_node(player)
            # Not a daemon, and joined below: a daemon thread still inside rcl_wait when the interpreter
            # finalises aborts the process ("terminate called without an active exception", ~1 exit in 15).
            spinner = threading.Thread(target=executor.spin, name="bag_player-executor")
            spinner.start()
            if opts.reset or opts.reset_service:
                services = opts.reset_service or RESET_SERVICES
                done = player.reset_slam(services)
                player.get_logger().info(f"reset {', '.join(done) if done else 'nothing'} before playing")
            if not player.wait_for_subscribers(opts.wait) and not stopped.is_set():
                player.get_logger().warn(
                    f"nobody subscribes to {player.topics.color} after {opts.wait:g} s; playing anyway"
                )
            if player.preload():
                player.get_logger().info(f"preloaded {player.stats.preloaded} of {player.message_count} messages")
            stats = player.play()
            player.get_logger().info(
                f"{'stopped' if stopped.is_set() else 'done'}: {stats.frames} frames, {stats.messages} messages, "
                f"{stats.lockstep_timeouts} timeouts"
            )
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        except (BagError, ValueError) as err:
            print(f"bag_player: error: {err}", file=sys.stderr)
            return 1
        finally:
            if player is not None:
                player.stop()
            executor.shutdown()
            if spinner is not None:
                spinner.join(timeout=10.0)
            if player is not None:
                player.destroy_node()
            rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
