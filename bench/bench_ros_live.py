"""Live through ROS beside ``sgs-slam run --realtime`` and lockstep: the same input, size and settings.

Three runs of one RGB-D sequence:

- **lockstep**: ``sgs-slam run`` processing every frame (the accuracy reference);
- **--realtime**: ``sgs-slam run --realtime`` releasing frames at their recorded stamps;
- **ROS**: the sequence as an MCAP bag (converted once when a dataset folder is given), played at
  its recorded rate by ``bag_player`` into ``slam_node`` (two processes, live, at the node's
  ``downscale`` processing size); the poses it publishes are recorded by this process.

For each: frames in, frames tracked (a pose came out), the tracked fraction and the ATE RMSE of the
tracked frames' poses (camera centres after SE(3) alignment to the ground truth). The issue's
checks: the ROS fraction within 10 points of ``--realtime``'s, its ATE within 1.5x of lockstep.

    python bench/bench_ros_live.py ../shared/data/tum_fr3_teddy --downscale 4 \\
        [--set tracking.method=gauss_newton ...] [--no-append]
"""

from __future__ import annotations

import argparse
import json
import random
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bags.format import is_bag
from bench.bench_replay_loss import replay
from bench.common import append_section, markdown_table
from sgs_slam_core.datasets import open_dataset
from sgs_slam_core.metrics import ate


@dataclass(frozen=True)
class Outcome:
    """One run's frame counts and accuracy."""

    name: str
    frames_in: int
    tracked: int
    ate_cm: float | None
    map_steps: float | None  # mapping steps per mapped frame

    @property
    def fraction(self) -> float:
        return self.tracked / max(self.frames_in, 1)

    def row(self) -> list[object]:
        ate_text = "n/a" if self.ate_cm is None else f"{self.ate_cm:.2f}"
        steps = "n/a" if self.map_steps is None else f"{self.map_steps:.1f}"
        return [self.name, self.frames_in, self.tracked, f"{100 * self.fraction:.0f} %", ate_text, steps]


def bag_of(source: Path, work: Path, compress: str) -> Path:
    """``source`` if it is a bag, else the dataset converted (full size: the node applies ``downscale``)."""
    if is_bag(source):
        return source
    bag = work / f"{source.name}_bag"
    cmd = [sys.executable, "-m", "bags.cli", "convert", str(source), "--out", str(bag), "--compress", compress]
    subprocess.run(cmd, check=True, capture_output=True, text=True)
    return bag


def cli_run(source: Path, out: Path, args: argparse.Namespace, realtime: bool) -> Outcome:
    """``sgs-slam run`` lockstep or at the recorded stamps; its counts and ATE from metrics.json."""
    cmd = [sys.executable, "-m", "sgs_slam_core.cli", "run", str(source), "--out", str(out), "--overwrite", "--quiet"]
    cmd += ["--downscale", str(args.downscale), "--preset", args.preset]
    cmd += ["--realtime", "stamps"] if realtime else []
    for item in args.overrides:
        cmd += ["--set", item]
    proc = subprocess.run(cmd, check=False, capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"bench_ros_live: {' '.join(cmd)} failed:\n{proc.stderr[-2000:]}")
    m = json.loads((out / "metrics.json").read_text())
    ate_m = m.get("ate_rmse_m")
    name = "sgs-slam run --realtime" if realtime else "sgs-slam run (lockstep)"
    ate_cm = None if ate_m is None else 100 * ate_m
    return Outcome(name, m["frames_in"], m["frames_tracked"], ate_cm, m.get("map_steps_per_frame"))


def published_ate_cm(bag: Path, poses: dict[int, np.ndarray]) -> float | None:
    """ATE RMSE (cm) of the poses a node published (stamp ns -> c2w) against the bag's ground truth; None under 3."""
    dataset = open_dataset(bag)
    truth = {stamp: dataset.ground_truth(i) for i, stamp in enumerate(dataset.stamps_ns)}  # no image decoded
    pairs = [(c2w, truth[stamp]) for stamp, c2w in sorted(poses.items()) if truth.get(stamp) is not None]
    if len(pairs) < 3:
        return None
    return 100 * ate(np.stack([p for p, _ in pairs]), np.stack([g for _, g in pairs])).rmse


def ros_run(bag: Path, args: argparse.Namespace) -> Outcome:
    """The bag at its recorded rate into ``slam_node``; the published poses against the bag's ground truth."""
    from bench.pose_recorder import PoseRecorder  # noqa: PLC0415 - rclpy only for this run

    domain = random.randint(1, 100)
    params = ("map_alignment:=optical", *args.params)
    if args.overrides:  # an empty list has no type a parameter can be declared with
        params += ("overrides:=[" + ",".join(f"'{o}'" for o in args.overrides) + "]",)
    with PoseRecorder(domain) as recorder:

        def node_ready() -> None:  # as --realtime starts its clock once the SLAM is built: play once the node spins
            recorder.wait_spinning("tracking_node", 120.0)

        counts = replay(bag, "shm", args.downscale, args.preset, args.semantics, params, domain, node_ready)
        poses = recorder.wait_quiet(5.0)
    ate_cm = published_ate_cm(bag, poses)
    steps = counts.get("mapping_steps_per_frame")
    return Outcome("bag_player -> slam_node", int(counts["frames_in"]), len(poses), ate_cm, steps)


def summary(lockstep: Outcome | None, realtime: list[Outcome], ros: list[Outcome]) -> str:
    """The medians over the repeats and the issue's two checks on them."""

    def median_ate(runs: list[Outcome]) -> float | None:
        values = [r.ate_cm for r in runs if r.ate_cm is not None]
        return float(np.median(values)) if values else None

    rt_fraction, ros_fraction = (float(np.median([r.fraction for r in runs])) for runs in (realtime, ros))
    rt_ate, ros_ate = median_ate(realtime), median_ate(ros)

    def cm(value: float | None) -> str:
        return "n/a" if value is None else f"{value:.2f} cm"

    points = 100 * (ros_fraction - rt_fraction)
    lines = [
        f"Medians over {len(ros)} repeats: --realtime {100 * rt_fraction:.0f} % tracked at ATE {cm(rt_ate)};",
        f"ROS {100 * ros_fraction:.0f} % at {cm(ros_ate)}.",
        f"ROS tracked fraction {points:+.0f} points against --realtime (target: within 10).",
    ]
    if lockstep is not None and lockstep.ate_cm and ros_ate is not None:
        lines.append(f"ROS ATE {ros_ate / lockstep.ate_cm:.2f}x lockstep's (target: at most 1.5x).")
    return " ".join(lines)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("input", type=Path, help="a dataset folder (converted to a bag once) or an MCAP bag")
    p.add_argument("--downscale", type=float, default=4.0, help="processing size: the input divided by this")
    p.add_argument("--preset", default="tum")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    p.add_argument(
        "--param", dest="params", action="append", default=[], metavar="NAME:=VALUE", help="a slam_node parameter"
    )
    p.add_argument("--semantics", action="store_true", help="the input has labels: the node subscribes them")
    p.add_argument(
        "--compress", choices=["zstd", "none"], default="zstd", help="chunk compression of the bag a dataset becomes"
    )
    p.add_argument("--repeats", type=int, default=3, help="live runs of each path (a live run varies run to run)")
    p.add_argument("--skip-lockstep", action="store_true", help="no lockstep run (its ATE is then not compared)")
    p.add_argument("--no-append", action="store_true")
    args = p.parse_args()
    work = Path(tempfile.mkdtemp(prefix="ros-live-"))
    try:
        bag = bag_of(args.input, work, args.compress)
        lockstep = None if args.skip_lockstep else cli_run(args.input, work / "lockstep", args, realtime=False)
        realtime, ros = [], []
        for _ in range(args.repeats):  # alternating, so a slow spell of the machine hits both paths
            realtime.append(cli_run(args.input, work / "realtime", args, realtime=True))
            ros.append(ros_run(bag, args))
            print(" | ".join(map(str, realtime[-1].row() + ros[-1].row())), flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    rows = [
        r.row()
        for r in ([lockstep] if lockstep else []) + [x for pair in zip(realtime, ros, strict=True) for x in pair]
    ]
    table = markdown_table(["run", "frames in", "tracked", "tracked %", "ATE cm", "mapping steps/frame"], rows)
    text = f"{table}\n\n{summary(lockstep, realtime, ros)}"
    print(text)
    if not args.no_append:
        sets = ", ".join(args.overrides) or "none"
        params = ", ".join(args.params) or "defaults"
        note = (
            f"`{args.input.name}` (bag chunks: {args.compress}), preset {args.preset}, downscale {args.downscale:g}, "
            f"overrides {sets}, node parameters {params}; "
            "`bag_player` at the recorded rate into `slam_node` (shared memory, two processes, played once the "
            "node spins); each live path run repeatedly, alternating"
        )
        append_section(f"Live through ROS against --realtime: {args.input.name}", note + "\n\n" + text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
