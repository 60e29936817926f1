"""``sgs-slam synth``: write a synthetic semantic RGB-D sequence (SGS-SLAM Replica layout)."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from sgs_slam_core.cli.progress import ProgressBar
from sgs_slam_core.synthetic import SYNTH_PRESETS, generate, preset_config


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the sub-command."""
    p = sub.add_parser(
        "synth",
        help="generate a synthetic room sequence with exact ground truth",
        description="Ray-cast the built-in room (13 NYU40 classes) along a smooth trajectory and write "
        "frames/, depths/, semantic_ids/, semantic_colors/, traj.txt, camera.yaml and labels.yaml.",
    )
    p.add_argument("out", type=Path, help="output folder (must be empty or absent)")
    p.add_argument(
        "--preset", choices=sorted(SYNTH_PRESETS), default="room", help="tiny: 64x48, 12 frames; room: 320x240, 200"
    )
    p.add_argument("--frames", type=int, help="number of frames")
    p.add_argument("--width", type=int, help="image width (px)")
    p.add_argument("--height", type=int, help="image height (px)")
    p.add_argument("--seed", type=int, help="scene and noise seed")
    p.add_argument("--trajectory", choices=["orbit", "walk", "look"], help="camera path")
    p.add_argument("--depth-noise", type=float, help="multiple of Kinect v1 axial noise (0 = exact)")
    p.add_argument("--depth-holes", type=float, help="fraction of pixels without depth")
    p.add_argument("--label-noise", type=float, help="fraction of pixels with a wrong class")
    p.add_argument("--label-erosion", type=int, help="unlabelled band at class boundaries (px)")
    p.add_argument("--overwrite", action="store_true", help="replace a non-empty output folder")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Generate the sequence."""
    cfg = preset_config(
        args.preset,
        frames=args.frames,
        width=args.width,
        height=args.height,
        seed=args.seed,
        trajectory=args.trajectory,
        depth_noise=args.depth_noise,
        depth_holes=args.depth_holes,
        label_noise=args.label_noise,
        label_erosion=args.label_erosion,
    )
    bar = ProgressBar(cfg.frames, "synth")
    t0 = time.perf_counter()
    generate(args.out, cfg, overwrite=args.overwrite, progress=lambda done, _: bar.update(done))
    print(f"wrote {cfg.frames} frames of {cfg.width}x{cfg.height} to {args.out} in {time.perf_counter() - t0:.1f} s")
    return 0
