"""Transport benchmark: 640x480 RGB-D + labels at 30 Hz from one process to another, per QoS and transport.

Each cell of the table is a fresh pair of ``sgs_slam_ros.transport_probe`` processes on its own DDS
domain: a publisher sending ``--frames`` frames (rgb8 colour, 16UC1 depth, 16UC1 labels, CameraInfo)
at ``--rate`` Hz as a camera driver or ``bag_player`` does, and a subscriber receiving them with
Python callbacks as the SLAM nodes do, with and without ``--busy`` threads keeping its cores busy
(as tracking does). Received counts, and in brackets the frames the stamp gaps count as lost.

    python bench/bench_transport.py [--frames 300] [--busy 2] [--no-append]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import append_section, markdown_table

REPO = Path(__file__).resolve().parents[1]
PROFILE = REPO / "config" / "fastdds_shm.xml"
TOPICS = ("/camera/color/image_raw", "/camera/depth/image_raw", "/camera/semantic/image_raw")
INFO = "/camera/color/camera_info"


@dataclass(frozen=True)
class Cell:
    """One configuration: publisher and subscriber reliability, and the Fast DDS transport."""

    publisher: str  # reliable | best_effort
    subscriber: str  # an input_qos choice of the nodes
    transport: str  # default | shm (config/fastdds_shm.xml in both) | shm-writer (in the publisher only)


CELLS = (
    Cell("reliable", "best_effort", "default"),  # bag_player into the nodes before this change
    Cell("reliable", "best_effort", "shm"),
    Cell("reliable", "best_effort", "shm-writer"),  # bag_player with the profile, the nodes without
    Cell("reliable", "reliable", "default"),
    Cell("reliable", "reliable", "shm"),
    Cell("best_effort", "best_effort", "default"),  # a sensor-data driver
    Cell("best_effort", "best_effort", "shm"),
)


def run_cell(cell: Cell, frames: int, rate: float, busy: int, domain: int, profile: Path, depth: int) -> dict:
    """One publisher/subscriber pair; returns the subscriber's counts."""
    env = {k: v for k, v in os.environ.items() if k != "_ROS_WHEELS_BOOTSTRAP_COMPLETE"}
    env |= {"ROS_DOMAIN_ID": str(domain), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    env.pop("FASTRTPS_DEFAULT_PROFILES_FILE", None)
    shm = env | {"FASTRTPS_DEFAULT_PROFILES_FILE": str(profile)}
    me = [sys.executable, "-m", "sgs_slam_ros.transport_probe"]
    timeout = frames / rate + 40.0
    sub = subprocess.Popen(
        [*me, "sub", "--qos", cell.subscriber, "--frames", str(frames), "--busy", str(busy), "--depth", str(depth)],
        env=shm if cell.transport == "shm" else env,
        stdout=subprocess.PIPE,
        text=True,
    )
    pub = subprocess.Popen(
        [*me, "pub", "--qos", cell.publisher, "--frames", str(frames), "--rate", str(rate)],
        env=env if cell.transport == "default" else shm,
    )
    out, _ = sub.communicate(timeout=timeout)
    pub.wait(timeout=30)
    return json.loads(out.strip().splitlines()[-1])


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--rate", type=float, default=30.0)
    p.add_argument("--busy", type=int, default=0, help="subscriber threads keeping the cores busy")
    p.add_argument("--depth", type=int, default=10, help="reader history depth (the nodes' sync_queue_size)")
    p.add_argument("--profile", type=Path, default=PROFILE, help="Fast DDS profile of the shm cells")
    p.add_argument("--cells", help="comma-separated indices of the cells to run (default: all)")
    p.add_argument("--no-append", action="store_true", help="print only; do not append to BENCHMARKS.md")
    args = p.parse_args()
    rows = []
    picked = [int(i) for i in args.cells.split(",")] if args.cells else range(len(CELLS))
    for i in picked:
        cell = CELLS[i]
        for busy in sorted({0, args.busy}):
            r = run_cell(cell, args.frames, args.rate, busy, 60 + i, args.profile, args.depth)
            got, lost = r["received"], r["lost_by_gaps"]
            rows.append(
                [
                    cell.publisher,
                    cell.subscriber,
                    cell.transport,
                    str(busy),
                    *(f"{got[t]} ({lost[t]})" for t in (*TOPICS, INFO)),
                ]
            )
            print(" | ".join(rows[-1]), flush=True)
    header = [
        "writer (depth 100)",
        f"reader (input_qos, depth {args.depth})",
        "transport",
        "busy threads",
        "colour (lost)",
        "depth (lost)",
        "labels (lost)",
        "camera_info (lost)",
    ]
    table = markdown_table(header, rows)
    print(table)
    if not args.no_append:
        note = (
            f"{args.frames} frames of 640x480 rgb8 + 16UC1 depth + 16UC1 labels + CameraInfo at {args.rate:g} Hz "
            "between two processes; received (frames the stamp gaps count as lost)"
        )
        append_section(f"Transport: 640x480 RGB-D + labels at {args.rate:g} Hz, two processes", note + "\n\n" + table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
