"""``main()`` helper: init, spin, Ctrl-C and clean shutdown for every executable."""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence

import rclpy
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node

from sgs_slam_core.errors import SgsSlamError

__all__ = ["run_nodes"]


def run_nodes(build: Callable[[], Sequence[Node]], args: Sequence[str] | None = None, threads: int = 4) -> int:
    """Create the nodes with ``build`` and spin them until Ctrl-C or shutdown; returns the exit code."""
    rclpy.init(args=list(args) if args is not None else sys.argv)
    nodes: Sequence[Node] = ()
    executor = MultiThreadedExecutor(num_threads=threads)
    try:
        nodes = build()
        for node in nodes:
            executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ValueError, SgsSlamError) as err:  # bad parameters or config (preset, config_file): one line, exit 1
        print(f"error: {err}", file=sys.stderr)
        return 1
    finally:
        executor.shutdown()
        for node in nodes:
            close = getattr(node, "close", None)
            if close:
                close()
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
