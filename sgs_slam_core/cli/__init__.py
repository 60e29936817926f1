"""``sgs-slam``: the offline command line. Library errors become one line on stderr and exit 1."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from sgs_slam_core.errors import SgsSlamError

__all__ = ["main", "run_command"]


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with one sub-command per module in this package.

    The command modules are imported here, not at package import, so library modules may use
    ``sgs_slam_core.cli.progress`` without importing every command (and the runner with them).
    """
    from sgs_slam_core.cli import (  # noqa: PLC0415
        compare,
        demo,
        edit,
        evaluate,
        export,
        map_labels,
        render_views,
        run,
        synth,
    )

    parser = argparse.ArgumentParser(prog="sgs-slam", description="Semantic Gaussian-splatting SLAM, offline tools.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module in (run, evaluate, compare, synth, demo, edit, render_views, map_labels, export):
        module.add_parser(sub)
    return parser


def run_command(prog: str, parser: argparse.ArgumentParser, argv: Sequence[str] | None) -> int:
    """Parse, run ``args.func``; a library error becomes one line on stderr and exit code 1."""
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except SgsSlamError as err:
        print(f"{prog}: error: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``sgs-slam`` console script."""
    return run_command("sgs-slam", build_parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
