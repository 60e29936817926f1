"""``main()`` helper: init, spin, Ctrl-C and clean shutdown for every executable.

A user's mistake (a bad ``--ros-args`` rule, a parameter of the wrong type or out of range, an
unknown preset or config key) prints one line naming it and exits 1, never a traceback.

SIGINT and SIGTERM are handled here rather than by rclpy: rclpy's handler shuts the context down at
once, while a SLAM worker thread may be publishing on it (seen as a SIGSEGV at Ctrl-C). Here a
signal only stops the spin loop; each node's ``finish()`` (where it has one: the mapping node saves
its map) runs, then the nodes' workers are stopped before the context goes. A second signal exits
at once, without waiting for either.

Before ``rclpy.init`` the process's DDS transport is chosen (``--transport shm|default`` before
``--ros-args``; shm by default: see :mod:`sgs_slam_ros.transport`).

The nodes are spun by one executor thread: their callbacks only hand work to the SLAM pipeline's
threads, and rclpy's multi-threaded executor spends so much time in Python between callbacks that,
holding the GIL, it starves those threads of it: tracking falls far behind the camera. That thread
is rclpy's events executor by default (``--executor events|single`` before ``--ros-args``): it
waits for the middleware's events in C++ where the single-threaded executor rebuilds its wait set in
Python for every message, time that live mapping on a small CPU is short of. It is still in rclpy's
``experimental`` module; ``--executor single`` is the fallback.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager, redirect_stderr

import rclpy
from rclpy.context import Context
from rclpy.exceptions import ParameterException
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import remove_ros_args

from sgs_slam_core.errors import SgsSlamError
from sgs_slam_ros.transport import TRANSPORTS, apply_transport

__all__ = ["EXECUTORS", "USER_ERRORS", "make_executor", "run_nodes", "stop_on_signals"]

# what a user's command line can cause while the nodes are built
USER_ERRORS = (ValueError, SgsSlamError, ParameterException)
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
POLL_S = 0.1  # how long the spin loop waits for work before it looks at the stop flag again
EXECUTORS = ("events", "single")


@contextmanager
def stop_on_signals(on_signal: Callable[[], None]) -> Iterator[None]:
    """While inside, the first SIGINT/SIGTERM calls ``on_signal``; a second one exits the process (code 130).

    Use with ``rclpy.init(signal_handler_options=SignalHandlerOptions.NO)``, so that the context
    stays valid until the caller has stopped what publishes on it.
    """
    if threading.current_thread() is not threading.main_thread():  # Python allows handlers only there
        yield
        return
    signalled = threading.Event()

    def handle(signum: int, _frame: object) -> None:
        if signalled.is_set():
            print("second signal: exiting without waiting for the workers", file=sys.stderr)
            os._exit(130)
        signalled.set()
        on_signal()

    previous = {s: signal.signal(s, handle) for s in STOP_SIGNALS}
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


def _fail(argv: Sequence[str], err: BaseException) -> int:
    text = str(err).splitlines()[0] if str(err) else type(err).__name__
    print(f"{os.path.basename(argv[0]) if argv else 'sgs_slam_ros'}: error: {text}", file=sys.stderr)
    return 1


def _options(argv: Sequence[str]) -> argparse.Namespace:
    """The non-ROS arguments: ``--transport`` and ``--executor``."""
    prog = os.path.basename(argv[0]) if argv else "sgs_slam_ros"
    parser = argparse.ArgumentParser(prog=prog)
    parser.add_argument(
        "--transport",
        choices=TRANSPORTS,
        default="shm",
        help="DDS transport: shm (whole frames through shared memory) or default",
    )
    parser.add_argument(
        "--executor",
        choices=EXECUTORS,
        default="events",
        help="events: rclpy's events executor (experimental in rclpy); single: its single-threaded one",
    )
    return parser.parse_args(remove_ros_args(list(argv))[1:])


def make_executor(name: str, context: Context | None = None) -> Executor:
    """The executor ``name`` (one of :data:`EXECUTORS`) on ``context`` (default: rclpy's, once initialised)."""
    if name == "events":
        from rclpy.experimental import EventsExecutor  # noqa: PLC0415 - experimental: only when chosen

        # it enables faulthandler on sys.stderr, which must then be a real file (not pytest's capture)
        with redirect_stderr(sys.__stderr__ or sys.stderr):
            return EventsExecutor(context=context)
    if name == "single":
        return SingleThreadedExecutor(context=context)
    raise ValueError(f"executor must be one of {', '.join(EXECUTORS)}, got {name!r}")


def run_nodes(build: Callable[[], Sequence[Node]], args: Sequence[str] | None = None) -> int:
    """Create the nodes with ``build`` and spin them until Ctrl-C or shutdown; returns the exit code."""
    argv = list(args) if args is not None else list(sys.argv)
    try:
        options = _options(argv)
        transport = apply_transport(options.transport)
        rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    except RuntimeError as err:  # rclpy's RCLError: an unparsable --ros-args rule
        return _fail(argv, err)
    nodes: Sequence[Node] = ()
    executor = make_executor(options.executor)
    stop = threading.Event()
    with stop_on_signals(stop.set):
        try:
            nodes = build()
            nodes[0].get_logger().info(f"transport: {transport}; executor: {options.executor}")
            for node in nodes:
                executor.add_node(node)
            while not stop.is_set() and rclpy.ok():
                executor.spin_once(timeout_sec=POLL_S)
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        except USER_ERRORS as err:
            return _fail(argv, err)
        finally:
            for node in nodes:  # the work in hand first (e.g. the map saved), while every node still runs
                finish = getattr(node, "finish", None)
                if finish:
                    finish()
            for node in nodes:  # workers next: they publish through the nodes and the context
                close = getattr(node, "close", None)
                if close:
                    close()
            executor.shutdown()
            for node in nodes:
                node.destroy_node()
            rclpy.try_shutdown()
    return 0
