"""Replay benchmark: a bag played at its recorded rate by ``bag_player`` into ``slam_node``, two processes.

Counts what the issue "A live camera that works end to end" measured: colour frames the player sent,
frames that reached the node (``frames_in``), frames the node counted as lost (``frames_lost``, from
stamp gaps; the gaps already in the bag, where the camera or the converter left frames out, are
counted by the same rule and subtracted to give the frames lost in transport) and the node's own
drops, read from the node's final log line, for each transport (``--transport shm``, the default,
and Fast DDS's built-in ``default``). The node runs live (not lockstep) at ``--downscale``, so it is
busy as it would be with a camera.

    python bench/bench_replay_loss.py BAG [--downscale 1] [--preset tum] [--no-append]
"""

from __future__ import annotations

import argparse
import os
import random
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bags.layout import BagTopics
from bags.reader import bag_file, open_index
from bench.common import append_section, markdown_table
from sgs_slam_ros.stream_gaps import StreamGaps

REMAPS = ("rgb/image:=/camera/color/image_raw", "depth/image:=/camera/depth/image_raw",
          "rgb/camera_info:=/camera/color/camera_info", "semantic/image:=/camera/semantic/image_raw")  # fmt: skip
_COUNT = re.compile(r"(\w+) (\d+)(?=,|$)")  # integer counts only: "frames_in 573, labels_fused 20"
_STEPS = re.compile(r"mapping_steps_per_frame ([\d.]+)")


def recorded_gaps(bag: Path) -> int:
    """Colour frames missing from the bag itself (the camera's or the converter's), as the node counts them."""
    index = open_index(bag_file(bag))
    try:
        colour = {cid for cid, ch in index.channels.items() if ch.topic == BagTopics().color}
        gaps = StreamGaps()
        for ref in sorted((m for m in index.messages if m.channel_id in colour), key=lambda m: m.log_time):
            gaps.add(ref.stamp_ns)
        return gaps.lost
    finally:
        index.close()


def replay(
    bag: Path,
    transport: str,
    downscale: float,
    preset: str,
    semantics: bool,
    params: tuple[str, ...] = (),
    domain: int | None = None,
    before_play: Callable[[], None] | None = None,
    remaps: tuple[str, ...] = REMAPS,
    side_node: tuple[str, ...] = (),
) -> dict[str, float]:
    """One replay on DDS domain ``domain`` (default: a random one); the node's final counts and the frames sent.

    ``params``: more ``NAME:=VALUE`` parameters of the node; ``remaps``: its topic remaps;
    ``before_play`` is called once the node is started (e.g. to wait until it spins). ``side_node``:
    the ``python -m`` arguments of another node run beside it (e.g. ``segmentation_node``), stopped
    with it; its final counts come back prefixed ``side_``.
    """
    domain = random.randint(1, 100) if domain is None else domain
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    env.pop("_ROS_WHEELS_BOOTSTRAP_COMPLETE", None)
    env.pop("FASTRTPS_DEFAULT_PROFILES_FILE", None)
    side = _start(side_node, env) if side_node else None
    node_params = (f"preset:={preset}", f"use_semantics:={str(semantics).lower()}", f"downscale:={downscale}")
    node_params += ("save_on_shutdown:=false", *params)  # a benchmark's map is not kept
    ros_args = [*(a for param in node_params for a in ("-p", param)), *(a for r in remaps for a in ("-r", r))]
    node = _start(("sgs_slam_ros.slam_node", "--transport", transport, "--ros-args", *ros_args), env)
    try:
        if before_play is not None:
            before_play()
        player = subprocess.run(
            [sys.executable, "-m", "sgs_slam_ros.bag_player", str(bag), "--transport", transport, "--wait", "120"],
            env=env,
            capture_output=True,
            text=True,
            check=False,
        )
    except BaseException:  # e.g. the node never spun: leave no node behind to load the next run's machine
        for proc in (node, side):
            if proc is not None:
                proc.kill()
                proc.wait()
        raise
    time.sleep(3.0)  # the last frames' callbacks
    node.send_signal(signal.SIGINT)
    counts = final_counts(node.communicate(timeout=300)[0], player.stderr)
    if side is not None:
        counts.update({f"side_{k}": v for k, v in _stop(side, side_node[0]).items()})
    return counts


def _start(module_args: tuple[str, ...], env: dict[str, str]) -> subprocess.Popen:
    """``python -m MODULE ARGS...`` with its output captured."""
    cmd = [sys.executable, "-m", *module_args]
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def _stop(proc: subprocess.Popen, name: str) -> dict[str, int]:
    """Stop a node as Ctrl-C does; the integer counts of its last ``final counts:`` line."""
    proc.send_signal(signal.SIGINT)
    log = proc.communicate(timeout=120)[0]
    final = [line for line in log.splitlines() if "final counts:" in line]
    if not final:
        raise RuntimeError(f"no counts from {name}: {log[-1500:]}")
    return {k: int(v) for k, v in _COUNT.findall(final[-1])}


def final_counts(node_log: str, player_log: str) -> dict[str, float]:
    """The node's last log line's counts (and mapping steps a frame), and the frames the player sent."""
    final = [line for line in node_log.splitlines() if "final counts:" in line]
    sent = re.search(r"done: (\d+) frames", player_log)
    if not final or sent is None:
        raise RuntimeError(f"no counts: player {player_log[-500:]} node {node_log[-1500:]}")
    counts: dict[str, float] = {k: int(v) for k, v in _COUNT.findall(final[-1])}
    counts["sent"] = int(sent.group(1))
    steps = _STEPS.search(final[-1])
    if steps is not None:
        counts["mapping_steps_per_frame"] = float(steps.group(1))
    return counts


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("bag", type=Path)
    p.add_argument("--downscale", type=float, default=1.0)
    p.add_argument("--preset", default="tum")
    p.add_argument("--semantics", action="store_true", help="the bag has label images: subscribe them")
    p.add_argument("--transports", nargs="+", default=["default", "shm"])
    p.add_argument("--no-append", action="store_true")
    args = p.parse_args()
    rows = []
    in_bag = recorded_gaps(args.bag)
    for transport in args.transports:
        c = replay(args.bag, transport, args.downscale, args.preset, args.semantics)
        transport_lost = c["frames_lost"] - in_bag
        uncounted = c["sent"] - c["frames_in"] - transport_lost  # lost after the last frame that arrived
        rows.append(
            [
                transport,
                c["sent"],
                c["frames_in"],
                c["frames_lost"],
                in_bag,
                transport_lost,
                uncounted,
                c["frames_tracked"],
                c["frames_dropped"],
                c["frames_rejected"],
            ]
        )
        print(" | ".join(map(str, rows[-1])), flush=True)
    header = ["transport", "sent", "frames_in", "frames_lost", "of them gaps in the bag", "lost in transport",
              "uncounted", "frames_tracked", "frames_dropped", "frames_rejected"]  # fmt: skip
    table = markdown_table(header, rows)
    print(table)
    if not args.no_append:
        note = (
            f"`bag_player {args.bag.name}` at its recorded rate into `slam_node` (live, preset {args.preset}, "
            f"downscale {args.downscale:g}), two processes; the node's final counts"
        )
        append_section("Replay: bag_player into slam_node, frames lost in transport", note + "\n\n" + table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
