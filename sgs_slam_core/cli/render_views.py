"""``sgs-slam render``: look at a map from given cameras, a trajectory, or an orbit."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from sgs_slam_core.cli.args import MAX_IMAGE_SIDE, FloatRange, IntRange
from sgs_slam_core.cli.errors import UsageError
from sgs_slam_core.datasets.base import check_rigid
from sgs_slam_core.errors import DatasetError, OutputError, ShapeError
from sgs_slam_core.fileio import read_text
from sgs_slam_core.geometry.views import orbit_poses
from sgs_slam_core.mapio import read_any_map
from sgs_slam_core.metrics.trajectory_io import read_tum_trajectory
from sgs_slam_core.runner.views import MapViews
from sgs_slam_core.slam.system import resolve_device

__all__ = ["add_parser", "read_c2w", "run"]

_SIDE = IntRange(1, MAX_IMAGE_SIDE)
_VIEWS = IntRange(1, 3600)
_RADIUS = FloatRange(0.0, None, lo_open=True)
_ELEVATION = FloatRange(-89.0, 89.0)


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the sub-command."""
    p = sub.add_parser(
        "render",
        help="render a map's colour, depth and semantics from cameras",
        description="Writes color_NNNNN.png, depth_NNNNN.png (uint16, mm) and with --semantic semantic_NNNNN.png.",
    )
    p.add_argument("map", type=Path, help="map (.sgsmap or .ply)")
    where = p.add_mutually_exclusive_group(required=True)
    where.add_argument("--c2w", type=Path, help="text file with one 4x4 camera-to-world matrix (16 numbers)")
    where.add_argument("--trajectory", type=Path, help="TUM trajectory file (t tx ty tz qx qy qz qw) of cameras")
    where.add_argument(
        "--orbit",
        type=_VIEWS,
        nargs="?",
        const=36,
        metavar="N",
        help=f"N cameras circling the map, looking at its centre ({_VIEWS.bounds}; 36)",
    )
    p.add_argument("--radius", type=_RADIUS, help=f"orbit radius in m ({_RADIUS.bounds}; default: from the map)")
    p.add_argument(
        "--elevation-deg",
        type=_ELEVATION,
        default=30.0,
        help=f"orbit camera elevation in degrees ({_ELEVATION.bounds}, default 30)",
    )
    p.add_argument("--out", type=Path, required=True, help="output folder (created; existing images are replaced)")
    p.add_argument(
        "--semantic", action="store_true", help="also write the semantic colour images and the class ids (uint16 PNG)"
    )
    p.add_argument(
        "--width", type=_SIDE, help=f"image width in px ({_SIDE.bounds}; default: the map's camera, else 640)"
    )
    p.add_argument(
        "--height", type=_SIDE, help=f"image height in px ({_SIDE.bounds}; default: the map's camera, else 480)"
    )
    p.add_argument("--device", choices=["auto", "cpu", "cuda"], default="auto", help="compute device")
    p.set_defaults(func=run)


def read_c2w(path: Path) -> np.ndarray:  # [4, 4]
    """A camera-to-world matrix from a text file of 16 (or 12: the top 3 rows) numbers."""
    text = read_text(path, "camera pose file", max_bytes=1 << 16)
    try:
        values = np.array(text.replace(",", " ").split(), dtype=np.float64)
    except ValueError as err:
        raise ShapeError(f"{path}: not a matrix of numbers ({err})") from err
    if values.size not in (12, 16):
        raise ShapeError(f"{path}: expected 16 numbers (a 4x4 matrix), found {values.size}")
    pose = np.eye(4)
    pose[: values.size // 4] = values.reshape(-1, 4)
    return check_rigid(pose, str(path), ShapeError, tolerance=1e-4)


def orbit(views: MapViews, count: int, radius: float | None, elevation_deg: float) -> list[np.ndarray]:
    """Cameras circling the map's opaque Gaussians; up is opposite the saved cameras' mean image-down axis."""
    g = views.gaussians
    means = g.means[g.opacities > 0.5].detach().cpu().numpy().astype(np.float64)
    if len(means) == 0:
        raise ShapeError("the map has no opaque Gaussian to look at")
    center = np.median(means, axis=0)
    traj = views.saved.trajectory
    up = -np.mean([c2w[:3, 1] for _, _, c2w in traj], axis=0) if traj else np.array([0.0, 0.0, 1.0])
    up /= np.linalg.norm(up)
    if radius is None:
        offsets = means - center
        horizontal = offsets - np.outer(offsets @ up, up)
        radius = 1.5 * float(np.percentile(np.linalg.norm(horizontal, axis=1), 90))
    return orbit_poses(center, max(radius, 1e-3), elevation_deg, count, up)


def run(args: argparse.Namespace) -> int:
    """Load the map, build the cameras, render and write."""
    if args.out.exists() and not args.out.is_dir():
        raise OutputError(f"--out {args.out} exists and is not a folder")
    views = MapViews(read_any_map(args.map), resolve_device(args.device))
    k = views.intrinsics(args.width, args.height)
    if max(k.width, k.height) > MAX_IMAGE_SIDE:
        raise UsageError(f"views would be {k.width}x{k.height} px; give --width and --height up to {MAX_IMAGE_SIDE}")
    if args.c2w is not None:
        poses = [read_c2w(args.c2w)]
    elif args.trajectory is not None:
        poses = list(read_tum_trajectory(args.trajectory)[1])  # finite rotations, checked per line
        if not poses:
            raise DatasetError(f"{args.trajectory} holds no pose")
    else:
        poses = orbit(views, args.orbit, args.radius, args.elevation_deg)
    written = views.write(poses, k, args.out, args.semantic)
    print(f"rendered {len(poses)} views at {k.width}x{k.height}: {len(written)} images in {args.out}")
    return 0
