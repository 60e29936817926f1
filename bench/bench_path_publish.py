"""What publishing ``~/path`` costs as the path grows: the reason it goes out at ``path_rate_hz``.

A ``nav_msgs/Path`` carries every kept pose, so one publication costs time linear in the path's
length (rclpy converts each PoseStamped to its C message). Published with every pose, as the
tracking node did, a live run at a camera's 30 Hz spends ``30 x`` that per second on its tracking
thread; at ``path_rate_hz`` it spends ``rate x`` that on the executor.

    python bench/bench_path_publish.py [--lengths 100 1000 10000] [--no-append]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import rclpy
from nav_msgs.msg import Path as PathMsg
from rclpy.context import Context
from rclpy.signals import SignalHandlerOptions

from bench.common import append_section, markdown_table
from msg_adapters import stamp_to_ns
from sgs_slam_ros.messages import path_msg, pose_msg
from sgs_slam_ros.params import TRACKING

CAMERA_HZ = 30.0


def publish_ms(lengths: list[int], repeats: int) -> dict[int, float]:
    """Median ms of one Path publication of each length (nobody subscribed: conversion and hand-over only)."""
    ctx = Context()
    rclpy.init(
        context=ctx, domain_id=int(os.environ.get("ROS_DOMAIN_ID", "0")), signal_handler_options=SignalHandlerOptions.NO
    )
    node = rclpy.create_node("bench_path_publish", context=ctx)
    try:
        pub = node.create_publisher(PathMsg, "path", 1)
        poses = [pose_msg(np.eye(4), i * 33_333_333, "map") for i in range(max(lengths))]
        out = {}
        for n in lengths:
            times = []
            for _ in range(repeats):
                t0 = time.perf_counter()
                pub.publish(path_msg(poses[:n], stamp_to_ns(poses[n - 1].header.stamp), "map"))
                times.append(time.perf_counter() - t0)
            out[n] = 1e3 * float(np.median(times))
        return out
    finally:
        node.destroy_node()
        rclpy.shutdown(context=ctx)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--lengths", type=int, nargs="+", default=[100, 1000, 10000], help="poses in the path")
    p.add_argument("--repeats", type=int, default=20)
    p.add_argument("--no-append", action="store_true", help="print only, do not append to BENCHMARKS.md")
    args = p.parse_args()
    rate = next(s.default for s in TRACKING if s.name == "path_rate_hz")
    ms = publish_ms(args.lengths, args.repeats)
    rows = [
        [n, f"{m:.2f}", f"{CAMERA_HZ * m / 10:.1f} %", f"{rate * m / 10:.2f} %"] for n, m in ms.items()
    ]  # ms/s over 1000 ms/s, in percent: m x rate / 10
    table = markdown_table(
        [
            "poses in the path",
            "ms per publication",
            f"with every pose at {CAMERA_HZ:g} Hz (of a core)",
            f"at path_rate_hz {rate:g}",
        ],
        rows,
    )
    print(table)
    if not args.no_append:
        append_section("~/path publication cost by path length", table)


if __name__ == "__main__":
    main()
