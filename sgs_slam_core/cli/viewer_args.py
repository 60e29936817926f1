"""``--viewer`` / ``--viewer-save`` options of ``sgs-slam run``: a live view of the run without ROS."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from sgs_slam_core.cli.args import IntRange
from sgs_slam_core.viz import VIEWER_KINDS, ViewerOptions, ViewerSettings, kind_of_file, open_viewer
from sgs_slam_core.viz.viewer import StreamingViewer

__all__ = ["add_viewer_arguments", "start_viewer", "viewer_options_from_args"]


def add_viewer_arguments(p: argparse.ArgumentParser) -> None:
    """Register the viewer options."""
    g = p.add_argument_group("live view (optional extras: pip install 'sgs_slam_ros[viewer]')")
    g.add_argument(
        "--viewer",
        choices=VIEWER_KINDS,
        help="show the run live: camera path, current frame, rendered colour/classes and the map's "
        "points (rerun: spawns the Rerun viewer, or serves a web viewer without a display; "
        "foxglove: WebSocket server on ws://127.0.0.1:8765)",
    )
    g.add_argument(
        "--viewer-save",
        type=Path,
        metavar="FILE",
        help="record the same stream to FILE (.rrd for rerun, .mcap for foxglove); "
        "without --viewer only the file is written",
    )
    g.add_argument(
        "--viewer-port",
        type=IntRange(1, 65535),
        metavar="PORT",
        help="port of the live view (rerun gRPC 9876, foxglove WebSocket 8765 by default)",
    )
    g.add_argument(
        "--viewer-points-every",
        type=IntRange(1),
        default=10,
        metavar="N",
        help="send the map's points every N frames (default 10; always after the last frame)",
    )


def viewer_options_from_args(args: argparse.Namespace) -> ViewerOptions | None:
    """Validate the options (None without ``--viewer`` / ``--viewer-save``); nothing is started yet."""
    if args.viewer is None and args.viewer_save is None:
        return None
    kind = args.viewer or kind_of_file(args.viewer_save)
    return ViewerOptions(
        kind=kind,
        live=args.viewer is not None,
        save=args.viewer_save,
        port=args.viewer_port,
        settings=ViewerSettings(points_every=args.viewer_points_every),
    )


def start_viewer(options: ViewerOptions | None) -> StreamingViewer | None:
    """Open the backend and say on stderr where its stream goes."""
    if options is None:
        return None
    viewer = open_viewer(options)
    for line in viewer.where:
        print(line, file=sys.stderr)
    return viewer
