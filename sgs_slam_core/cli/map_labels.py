"""``sgs-slam labels``: the classes of a map with Gaussian counts and bounding boxes."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from sgs_slam_core.editing import label_summary
from sgs_slam_core.mapio import read_any_map

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the sub-command."""
    p = sub.add_parser("labels", help="list a map's classes with Gaussian counts and bounding boxes")
    p.add_argument("map", type=Path, help="map (.sgsmap or .ply)")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Print one row per class present in the map."""
    saved = read_any_map(args.map)
    rows = label_summary(saved.gaussians, saved.label_table)
    locked = set(saved.locked_labels)
    if args.json:
        print(
            json.dumps(
                [
                    {
                        "id": i,
                        "name": name,
                        "gaussians": n,
                        "bbox_min_m": [round(float(v), 4) for v in lo],
                        "bbox_max_m": [round(float(v), 4) for v in hi],
                        "locked": i in locked,
                    }
                    for i, name, n, lo, hi in rows
                ],
                indent=1,
            )
        )
        return 0
    print(f"{len(saved.gaussians)} Gaussians, {len(rows)} classes ({args.map})")
    print(f"{'id':>4}  {'class':<22} {'gaussians':>9}  {'bbox min (m)':<26} {'bbox max (m)':<26}")
    for i, name, n, lo, hi in rows:
        box = "  ".join(f"[{a[0]:7.3f} {a[1]:7.3f} {a[2]:7.3f}]" for a in (lo, hi))
        print(f"{i:>4}  {name[:22]:<22} {n:>9}  {box}{'  locked' if i in locked else ''}")
    return 0
