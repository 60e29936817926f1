"""``sgs-slam synth``: write a synthetic semantic RGB-D sequence (SGS-SLAM Replica layout)."""

from __future__ import annotations

import argparse
import shutil
import time
from pathlib import Path

from sgs_slam_core.cli.args import MAX_FRAMES, MAX_IMAGE_SIDE, MAX_SEED, FloatRange, IntRange
from sgs_slam_core.cli.errors import UsageError
from sgs_slam_core.runner.progress import ProgressBar
from sgs_slam_core.synthetic import SYNTH_PRESETS, generate, preset_config

__all__ = ["MAX_PIXELS", "add_parser", "run"]

MAX_PIXELS = 2048 * 2048  # the ray caster needs about 0.65 KB per pixel (2.7 GB at this size)
_SIDE = IntRange(8, MAX_IMAGE_SIDE)
_FRAMES = IntRange(1, MAX_FRAMES)
_SEED = IntRange(0, MAX_SEED)
_NOISE = FloatRange(0.0, 100.0)
_FRACTION = FloatRange(0.0, 1.0, hi_open=True)
_EROSION = IntRange(0, 64)


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
    p.add_argument("--frames", type=_FRAMES, help=f"number of frames ({_FRAMES.bounds})")
    p.add_argument("--width", type=_SIDE, help=f"image width in px ({_SIDE.bounds}; width x height <= {MAX_PIXELS:,})")
    p.add_argument("--height", type=_SIDE, help=f"image height in px ({_SIDE.bounds})")
    p.add_argument("--seed", type=_SEED, help=f"scene and noise seed ({_SEED.bounds})")
    p.add_argument("--trajectory", choices=["orbit", "walk", "look"], help="camera path")
    p.add_argument("--depth-noise", type=_NOISE, help=f"multiple of Kinect v1 axial noise, 0 = exact ({_NOISE.bounds})")
    p.add_argument("--depth-holes", type=_FRACTION, help=f"fraction of pixels without depth ({_FRACTION.bounds})")
    p.add_argument("--label-noise", type=_FRACTION, help=f"fraction of pixels with a wrong class ({_FRACTION.bounds})")
    p.add_argument("--label-erosion", type=_EROSION, help=f"unlabelled band at class edges, px ({_EROSION.bounds})")
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
    if cfg.width * cfg.height > MAX_PIXELS:
        pixels = cfg.width * cfg.height
        raise UsageError(f"--width x --height is {cfg.width}x{cfg.height} = {pixels:,} px; at most {MAX_PIXELS:,}")
    bar = ProgressBar(cfg.frames, "synth")
    t0 = time.perf_counter()
    fresh = not args.out.exists()
    try:
        generate(args.out, cfg, overwrite=args.overwrite, progress=lambda done, _: bar.update(done))
    except BaseException:
        if fresh or args.overwrite:  # a half-written sequence is of no use (--overwrite had emptied the folder)
            shutil.rmtree(args.out, ignore_errors=True)
        raise
    print(f"wrote {cfg.frames} frames of {cfg.width}x{cfg.height} to {args.out} in {time.perf_counter() - t0:.1f} s")
    return 0
