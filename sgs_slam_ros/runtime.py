"""``main()`` helper: init, spin, Ctrl-C and clean shutdown for every executable.

A user's mistake (a bad ``--ros-args`` rule, a parameter of the wrong type or out of range, an
unknown preset or config key) prints one line naming it and exits 1, never a traceback.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Sequence

import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node

from sgs_slam_core.errors import SgsSlamError

__all__ = ["USER_ERRORS", "run_nodes"]

# what a user's command line can cause while the nodes are built
USER_ERRORS = (ValueError, SgsSlamError, ParameterException)


def _fail(argv: Sequence[str], err: BaseException) -> int:
    text = str(err).splitlines()[0] if str(err) else type(err).__name__
    print(f"{os.path.basename(argv[0]) if argv else 'sgs_slam_ros'}: error: {text}", file=sys.stderr)
    return 1


def run_nodes(build: Callable[[], Sequence[Node]], args: Sequence[str] | None = None, threads: int = 4) -> int:
    """Create the nodes with ``build`` and spin them until Ctrl-C or shutdown; returns the exit code."""
    argv = list(args) if args is not None else list(sys.argv)
    try:
        rclpy.init(args=argv)
    except RuntimeError as err:  # rclpy's RCLError: an unparsable --ros-args rule
        return _fail(argv, err)
    nodes: Sequence[Node] = ()
    executor = MultiThreadedExecutor(num_threads=threads)
    try:
        nodes = build()
        for node in nodes:
            executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except USER_ERRORS as err:
        return _fail(argv, err)
    finally:
        executor.shutdown()
        for node in nodes:
            close = getattr(node, "close", None)
            if close:
                close()
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
