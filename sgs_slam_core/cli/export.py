"""``sgs-slam export``: a map as a 3DGS splat PLY or a coloured point cloud PLY."""

from __future__ import annotations

import argparse
from pathlib import Path

from sgs_slam_core.cli.args import FloatRange
from sgs_slam_core.errors import MapFileError
from sgs_slam_core.mapio import read_any_map, write_map_point_cloud, write_splat_ply

__all__ = ["add_parser", "run"]

_OPACITY = FloatRange(0.0, 1.0)


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the sub-command."""
    p = sub.add_parser(
        "export",
        help="export a map as a splat PLY (SuperSplat & co.) or a point cloud PLY (MeshLab, CloudCompare)",
    )
    p.add_argument("map", type=Path, help="map (.sgsmap or .ply)")
    p.add_argument("--out", type=Path, required=True, help="output .ply")
    p.add_argument("--points", action="store_true", help="a plain point cloud of the Gaussian centres")
    p.add_argument("--semantic", action="store_true", help="point colours from the class palette (with --points)")
    p.add_argument(
        "--min-opacity",
        type=_OPACITY,
        default=0.5,
        help=f"leave out fainter Gaussians (with --points; {_OPACITY.bounds}, 0.5)",
    )
    p.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Load and write."""
    if args.out.suffix.lower() != ".ply":
        raise MapFileError(f"--out must end in .ply, got {args.out.name}")
    if args.out.exists() and not args.overwrite:
        raise MapFileError(f"{args.out} exists (use --overwrite to replace it)")
    if args.semantic and not args.points:
        raise MapFileError("--semantic colours a point cloud: add --points")
    saved = read_any_map(args.map)
    if args.points:
        n = write_map_point_cloud(args.out, saved.gaussians, saved.label_table, args.semantic, args.min_opacity)
        print(f"wrote {n} points to {args.out}")
    else:
        write_splat_ply(args.out, saved.gaussians, saved.label_table)
        print(f"wrote {len(saved.gaussians)} Gaussians to {args.out}")
    return 0
