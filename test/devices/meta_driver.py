"""Every CLI path and the SLAM nodes with ``torch.set_default_device("meta")`` set first.

A tensor made without naming the caller's device lands on ``meta``; the first operation mixing it
with a real tensor fails (on a GPU the same bug mixes CPU and CUDA tensors). Run by
``test_meta_device.py`` in its own interpreter (the default device is process-wide):

    python -m test.devices.meta_driver WORK_DIR

Prints one line per step and exits 1 at the first step that fails.
"""

from __future__ import annotations

import sys
import traceback
from collections.abc import Callable
from pathlib import Path

import torch

torch.set_default_device("meta")  # before anything of the project runs

FAST = ["--set", "tracking.adam.iterations=6", "--set", "mapping.iterations=4", "--quiet"]


def cli(*args: str) -> Callable[[], None]:
    def step() -> None:
        from sgs_slam_core.cli import main

        rc = main(list(args))
        if rc != 0:
            raise RuntimeError(f"sgs-slam {' '.join(args)} exited {rc}")

    return step


def bag_convert(scene: Path, bag: Path) -> Callable[[], None]:
    def step() -> None:
        from bags.cli import main

        if main(["convert", str(scene), "--out", str(bag)]) != 0:
            raise RuntimeError("sgs-slam-bag convert failed")

    return step


def nodes(scene: Path, work: Path) -> Callable[[], None]:
    """slam_node in-process: a few lockstep frames, every output published, the map saved."""

    def step() -> None:
        import dataclasses

        import numpy as np

        from sgs_slam_core.datasets import open_dataset
        from sgs_slam_ros.slam_node import build_slam_nodes
        from test.polling import wait_for
        from test.ros.helpers import Feeder, Spinner, new_context, node_params, shut_down

        ds = open_dataset(scene)
        frames = [
            dataclasses.replace(ds[i], depth=(np.round(ds[i].depth * 1000) / 1000).astype(np.float32)) for i in range(4)
        ]
        ctx = new_context()
        built = build_slam_nodes(context=ctx, parameter_overrides=node_params(map_path=str(work / "node.sgsmap")))
        feeder = Feeder(ctx)
        spinner = Spinner(ctx, [*built, feeder])
        try:
            if not wait_for(feeder.connected, 10.0):
                raise RuntimeError("slam_node did not subscribe")
            for f in frames:
                feeder.publish(f)
                if not wait_for(lambda f=f: f.stamp_ns in feeder.poses, 60.0):
                    raise RuntimeError(f"no pose for frame {f.index} (see the node's log above)")
            mapping = built[1]
            if not mapping.pipeline.wait_idle(30.0) or mapping.pipeline.stats.errors:
                raise RuntimeError(f"pipeline errors: {mapping.pipeline.stats.last_error}")
            mapping.publish_renders()
            mapping.publish_points()
            mapping.publish_gaussians()
            from std_srvs.srv import Trigger

            response = mapping._save_map(Trigger.Request(), Trigger.Response())
            if not response.success:
                raise RuntimeError(response.message)
        finally:
            shut_down(ctx, [*built, feeder], spinner)

    return step


FOUR = ("--max-frames", "4")
TORCH = ("--set", "render.backend=torch")
GN = ("--set", "tracking.method=gauss_newton", "--set", "tracking.gauss_newton.semantic_scale_m=0.05")


def with_adam_polish(step: Callable[[], None]) -> Callable[[], None]:
    """``step`` with the Gauss-Newton tracker's two Adam steps after each solve (``ADAM_STEPS``)."""

    def polished() -> None:
        from sgs_slam_core.slam.trackers import gauss_newton

        saved, gauss_newton.ADAM_STEPS = gauss_newton.ADAM_STEPS, 2
        try:
            step()
        finally:
            gauss_newton.ADAM_STEPS = saved

    return polished


def steps(work: Path) -> list[tuple[str, Callable[[], None]]]:
    """Every CLI command and the node, each on a kernel path it has."""
    scene, run, bag = work / "tiny", work / "run", work / "bag"
    sgsmap = str(run / "map.sgsmap")
    move = ("--move-label", "table", "--translate", "0.2", "0", "0", "--rotate-deg", "0", "0", "10")
    return [
        ("synth", cli("synth", str(scene), "--preset", "tiny")),
        ("run (lockstep)", cli("run", str(scene), "--out", str(run), *FAST)),
        ("run (torch renderer)", cli("run", str(scene), "--out", str(work / "run_torch"), *FOUR, *FAST, *TORCH)),
        ("run --realtime", cli("run", str(scene), "--out", str(work / "run_rt"), "--realtime", "30", *FAST)),
        (
            "run (Gauss-Newton tracker)",
            with_adam_polish(cli("run", str(scene), "--out", str(work / "run_gn"), *FOUR, *FAST, *GN)),
        ),
        (
            "run (Gauss-Newton tracker, torch kernels)",
            cli("run", str(scene), "--out", str(work / "run_gn_torch"), *FOUR, *FAST, *TORCH, *GN),
        ),
        ("eval", cli("eval", str(run), "--no-write")),
        ("labels", cli("labels", sgsmap)),
        ("edit remove", cli("edit", sgsmap, "--remove-label", "chair", "--out", str(work / "e.sgsmap"))),
        ("edit move", cli("edit", sgsmap, *move, "--out", str(work / "m.sgsmap"))),
        ("render", cli("render", str(work / "m.sgsmap"), "--orbit", "2", "--semantic", "--out", str(work / "orbit"))),
        ("export ply", cli("export", sgsmap, "--out", str(work / "map.ply"))),
        ("export points", cli("export", sgsmap, "--points", "--semantic", "--out", str(work / "p.ply"))),
        ("bag convert", bag_convert(scene, bag)),
        ("run bag", cli("run", str(bag), "--out", str(work / "run_bag"), *FOUR, *FAST)),
        ("slam_node", nodes(scene, work)),
    ]


def main(work: Path) -> int:
    for name, step in steps(work):
        try:
            step()
        except BaseException:
            print(f"FAILED: {name}\n{traceback.format_exc()}", flush=True)
            return 1
        print(f"ok: {name}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1])))
