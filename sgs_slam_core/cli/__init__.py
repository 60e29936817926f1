"""``sgs-slam``: the offline command line.

Every failure ends in one line on stderr (see :mod:`sgs_slam_core.cli.errors`): exit 1 for the
user's input or environment, 2 for usage, 130 for Ctrl-C, 70 for a bug (traceback with ``--debug``).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from sgs_slam_core.cli.errors import debug_from_env, report

__all__ = ["add_debug_flag", "main", "run_command"]


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with one sub-command per module in this package.

    The command modules are imported here, not at package import, so importing one command (or
    ``sgs_slam_core.cli.errors``) does not import every command and the runner with them.
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
    add_debug_flag(parser, sub)
    return parser


def add_debug_flag(parser: argparse.ArgumentParser, sub: argparse._SubParsersAction) -> None:
    """``--debug`` before or after the sub-command: print the traceback of a failure."""
    text = "print the traceback of a failure (also: SGS_SLAM_DEBUG=1)"
    parser.add_argument("--debug", action="store_true", help=text)
    for command in sub.choices.values():
        command.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=text)


def run_command(
    prog: str,
    parser: argparse.ArgumentParser,
    argv: Sequence[str] | None,
    user_errors: tuple[type[BaseException], ...] = (),
) -> int:
    """Parse and run ``args.func``; any failure becomes one line on stderr and an exit code.

    ``user_errors``: further exception types (besides the core's typed errors and ``OSError``)
    that mean bad input rather than a bug.
    """
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except SystemExit:
        raise
    except BaseException as err:  # the one place every failure (Ctrl-C included) becomes a line
        return report(prog, err, getattr(args, "debug", False) or debug_from_env(), user_errors)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``sgs-slam`` console script."""
    return run_command("sgs-slam", build_parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
