"""Probe the image transport between two processes: one sends camera-like frames, the other counts them.

``python -m sgs_slam_ros.transport_probe pub`` sends ``--frames`` frames (rgb8 colour, 16UC1 depth,
16UC1 labels and CameraInfo, one stamp per frame, 640x480 by default) at ``--rate`` Hz, as a camera
driver or ``bag_player`` does; ``... sub`` receives them with Python callbacks and the nodes' input
QoS, as the SLAM nodes do (optionally while ``--busy`` threads keep the cores busy, as tracking does),
and prints one JSON line: messages received per topic and frames the stamp gaps say were lost. Both
apply ``--transport`` before ``rclpy.init``. ``bench/bench_transport.py`` runs the pairs it tabulates.
"""

from __future__ import annotations

import argparse
import json
import threading
import time
from collections.abc import Sequence

import numpy as np
import rclpy
import torch
from rclpy.executors import MultiThreadedExecutor
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image

from msg_adapters import stamp_to_ns
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_ros.messages import camera_info_msg, image_msg
from sgs_slam_ros.qos import INPUT_QOS_CHOICES, input_qos
from sgs_slam_ros.stream_gaps import StreamGaps
from sgs_slam_ros.transport import TRANSPORTS, apply_transport

__all__ = ["INFO", "TOPICS", "main"]

TOPICS = ("/camera/color/image_raw", "/camera/depth/image_raw", "/camera/semantic/image_raw")
INFO = "/camera/color/camera_info"
_WRITER_DEPTH = 100  # bag_player's history depth
_QUIET_S = 4.0  # the subscriber stops this long after the last message


def _writer_qos(name: str) -> QoSProfile:
    reliability = ReliabilityPolicy.RELIABLE if name == "reliable" else ReliabilityPolicy.BEST_EFFORT
    return QoSProfile(depth=_WRITER_DEPTH, reliability=reliability, history=HistoryPolicy.KEEP_LAST)


def publish(frames: int, rate: float, reliability: str, width: int, height: int) -> None:
    """The publisher: waits for the subscriber, then sends ``frames`` frames at ``rate`` Hz."""
    rclpy.init()
    node = rclpy.create_node("bench_camera")
    qos = _writer_qos(reliability)
    pubs = [node.create_publisher(Image, t, qos) for t in TOPICS]
    info_pub = node.create_publisher(CameraInfo, INFO, qos)
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 255, (height, width, 3), dtype=np.uint8)
    depth = rng.integers(500, 4000, (height, width), dtype=np.uint16)
    labels = rng.integers(0, 40, (height, width), dtype=np.uint16)
    k = Intrinsics(525.0, 525.0, width / 2 - 0.5, height / 2 - 0.5, width, height)
    end = time.monotonic() + 30.0
    while any(p.get_subscription_count() == 0 for p in [*pubs, info_pub]) and time.monotonic() < end:
        time.sleep(0.05)
    time.sleep(0.5)  # every reader matched on both sides
    period = 1.0 / rate
    t0 = time.monotonic()
    for i in range(frames):
        stamp = (i + 1) * round(1e9 * period)
        info_pub.publish(camera_info_msg(k, stamp, "cam"))
        for pub, (arr, enc) in zip(pubs, ((rgb, "rgb8"), (depth, "16UC1"), (labels, "16UC1")), strict=True):
            pub.publish(image_msg(arr, enc, stamp, "cam"))
        delay = t0 + (i + 1) * period - time.monotonic()
        if delay > 0:
            time.sleep(delay)
    time.sleep(2.0)  # reliable writers resend what is missing
    node.destroy_node()
    rclpy.try_shutdown()


def _burn(stop: threading.Event) -> None:
    a = torch.randn(256, 256)
    while not stop.is_set():
        a = torch.tanh(a @ a)  # releases the GIL, as the SLAM's tensor work does


def subscribe(frames: int, qos_name: str, busy: int, timeout_s: float, depth: int) -> None:
    """The subscriber: counts arrivals and stamp-gap losses per topic; prints one JSON line."""
    rclpy.init()
    node = rclpy.create_node("bench_slam")
    qos = input_qos(qos_name, depth)  # the nodes use sync_queue_size
    received = dict.fromkeys([*TOPICS, INFO], 0)
    gaps = {t: StreamGaps() for t in received}
    last = [time.monotonic()]

    def on(topic: str):
        def callback(msg) -> None:
            received[topic] += 1
            gaps[topic].add(stamp_to_ns(msg.header.stamp))
            last[0] = time.monotonic()

        return callback

    for t in TOPICS:
        node.create_subscription(Image, t, on(t), qos)
    node.create_subscription(CameraInfo, INFO, on(INFO), qos)
    stop = threading.Event()
    burners = [threading.Thread(target=_burn, args=(stop,), daemon=True) for _ in range(busy)]
    for b in burners:
        b.start()
    executor = MultiThreadedExecutor(num_threads=4)
    executor.add_node(node)
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        executor.spin_once(timeout_sec=0.1)
        if received[TOPICS[0]] and time.monotonic() - last[0] > _QUIET_S:
            break
        if min(received.values()) >= frames:
            break
    stop.set()
    print(json.dumps({"received": received, "lost_by_gaps": {t: g.lost for t, g in gaps.items()}}), flush=True)
    executor.shutdown()
    node.destroy_node()
    rclpy.try_shutdown()


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point: ``pub`` or ``sub``."""
    p = argparse.ArgumentParser(prog="transport_probe", description=__doc__.splitlines()[0])
    p.add_argument("role", choices=["pub", "sub"])
    p.add_argument(
        "--qos", default="reliable", help=f"pub: reliable or best_effort; sub: {', '.join(INPUT_QOS_CHOICES)}"
    )
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--rate", type=float, default=30.0, help="frames per second (pub)")
    p.add_argument("--size", type=int, nargs=2, default=(640, 480), metavar=("W", "H"), help="image size (pub)")
    p.add_argument("--busy", type=int, default=0, help="threads keeping the cores busy (sub)")
    p.add_argument("--depth", type=int, default=10, help="reader history depth (sub; the nodes' sync_queue_size)")
    p.add_argument("--transport", choices=TRANSPORTS, default="default")
    args = p.parse_args(argv)
    apply_transport(args.transport)
    if args.role == "pub":
        publish(args.frames, args.rate, args.qos, *args.size)
    else:
        subscribe(args.frames, args.qos, args.busy, args.frames / args.rate + 30.0, args.depth)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
