"""One side of ``bench/bench_ab.py``: runs the SLAM of whatever checkout is first on ``sys.path``.

Started by bench_ab.py with ``PYTHONPATH`` set to a checkout (this one or another commit's worktree);
uses only core APIs that every compared commit has. Protocol, one JSON object per line:
stdin ``{"frame": i}`` -> stdout ``{"track_s", "map_s", "total_s", "gaussians"}``; stdin
``{"finish": true}`` -> stdout ``{"ate_rmse_m", "frames", "num_gaussians", "source"}``; then it exits.
Loading a frame is not timed; the compiled kernels are built before the first frame.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

import sgs_slam_core
from sgs_slam_core.config import load_config
from sgs_slam_core.datasets import DatasetOptions, open_dataset
from sgs_slam_core.metrics import ate
from sgs_slam_core.slam.system import Slam


def _reply(obj: dict) -> None:
    sys.stdout.write(json.dumps(obj) + "\n")
    sys.stdout.flush()


def _warm_up(slam: Slam) -> None:
    prepare = getattr(slam, "prepare", None)
    if prepare is not None:
        prepare(lambda line: print(line, file=sys.stderr))
    elif slam.device.type == "cpu":  # commits before Slam.prepare: the renderer was the only kernel
        from sgs_slam_core.render import cpu_backend  # noqa: PLC0415

        cpu_backend.is_available()


def _step_times(step) -> tuple[float, float]:
    """(tracking, mapping) seconds of one step, from either result shape a compared commit has."""
    if hasattr(step, "track_time_s"):  # commits before StepResult held the track and map outcomes
        return step.track_time_s, step.map_time_s
    return step.track.time_s, step.map.time_s


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("input", type=Path)
    parser.add_argument("--preset", required=True)
    parser.add_argument("--downscale", type=float, default=1.0)
    parser.add_argument("--max-frames", type=int)
    parser.add_argument("--set", dest="overrides", action="append", default=[])
    args = parser.parse_args()
    config = load_config(args.preset, None, args.overrides)
    dataset = open_dataset(args.input, "auto", DatasetOptions(max_frames=args.max_frames, downscale=args.downscale))
    torch.manual_seed(config.seed)
    slam = Slam(config, dataset.label_table)
    _warm_up(slam)
    poses, gts = [], []
    _reply({"ready": True, "frames": len(dataset)})
    for line in sys.stdin:
        cmd = json.loads(line)
        if "frame" in cmd:
            frame = dataset[int(cmd["frame"])]
            t0 = time.perf_counter()
            step = slam.process(frame)
            total = time.perf_counter() - t0
            poses.append(step.c2w)
            gts.append(frame.gt_c2w)
            track_s, map_s = _step_times(step)
            _reply({"track_s": track_s, "map_s": map_s, "total_s": total, "gaussians": slam.num_gaussians})
        elif cmd.get("finish"):
            pairs = [(p, g) for p, g in zip(poses, gts, strict=True) if g is not None]
            rmse = None
            if len(pairs) > 2:
                rmse = ate(np.stack([p for p, _ in pairs]), np.stack([g for _, g in pairs])).rmse
            source = str(Path(sgs_slam_core.__file__).parents[1])
            _reply({"ate_rmse_m": rmse, "frames": len(poses), "num_gaussians": slam.num_gaussians, "source": source})
            return


if __name__ == "__main__":
    main()
