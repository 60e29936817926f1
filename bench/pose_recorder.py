"""Records the poses a ``slam_node`` publishes, from a thread of this process (for the live benches)."""

from __future__ import annotations

import threading
import time

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions

from msg_adapters import stamp_to_ns
from msg_adapters.pose import pose_to_c2w


class PoseRecorder:
    """Subscribes ``topic`` on DDS domain ``domain`` while open; ``poses``: stamp (ns) -> c2w [4, 4]."""

    def __init__(self, domain: int, topic: str = "/tracking_node/pose") -> None:
        self.poses: dict[int, np.ndarray] = {}
        self._last_message = time.monotonic()
        self._ctx = Context()
        rclpy.init(context=self._ctx, domain_id=domain, signal_handler_options=SignalHandlerOptions.NO)
        self._node = rclpy.create_node("bench_pose_recorder", context=self._ctx)
        qos = QoSProfile(depth=500, reliability=ReliabilityPolicy.RELIABLE)
        self._sub = self._node.create_subscription(PoseStamped, topic, self._on_pose, qos)
        self._spinning: set[str] = set()  # nodes whose /diagnostics came: their executor spins
        self._node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 10)
        self._executor = SingleThreadedExecutor(context=self._ctx)
        self._executor.add_node(self._node)
        self._thread = threading.Thread(target=self._executor.spin, name="pose-recorder", daemon=True)

    def __enter__(self) -> PoseRecorder:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._executor.shutdown()
        self._node.destroy_node()
        rclpy.shutdown(context=self._ctx)
        self._thread.join(5.0)

    def _on_pose(self, msg: PoseStamped) -> None:
        self.poses[stamp_to_ns(msg.header.stamp)] = pose_to_c2w(msg.pose)  # a republished pose keeps its stamp
        self._last_message = time.monotonic()

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        self._spinning.update(status.name for status in msg.status)

    def wait_spinning(self, node: str, timeout_s: float) -> None:
        """Return once a /diagnostics status whose name ends with ``node`` came; raise after ``timeout_s``."""
        end = time.monotonic() + timeout_s
        while not any(name.endswith(node) for name in self._spinning):
            if time.monotonic() > end:
                raise TimeoutError(f"no /diagnostics from {node} within {timeout_s:g} s")
            time.sleep(0.1)

    def wait_matched(self, timeout_s: float) -> None:
        """Return once a pose publisher is matched (poses sent before are lost); raise after ``timeout_s``."""
        end = time.monotonic() + timeout_s
        while self._sub.get_publisher_count() == 0:
            if time.monotonic() > end:
                raise TimeoutError(f"no publisher of {self._sub.topic_name} within {timeout_s:g} s")
            time.sleep(0.1)

    def wait_quiet(self, quiet_s: float) -> dict[int, np.ndarray]:
        """The poses once none has come for ``quiet_s`` seconds."""
        while time.monotonic() - self._last_message < quiet_s:
            time.sleep(0.1)
        return dict(self.poses)


def main() -> int:
    """Record poses until SIGINT or SIGTERM, then write them as JSON (stamp ns -> c2w rows), e.g. on another host."""
    import argparse  # noqa: PLC0415 - only for the command line
    import json  # noqa: PLC0415
    import os  # noqa: PLC0415
    import signal  # noqa: PLC0415
    from pathlib import Path  # noqa: PLC0415

    p = argparse.ArgumentParser(description=main.__doc__)
    p.add_argument("out", type=Path, help="JSON file written at the end")
    p.add_argument("--topic", default="/tracking_node/pose")
    args = p.parse_args()
    stop = threading.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stop.set())
    with PoseRecorder(int(os.environ.get("ROS_DOMAIN_ID", "0")), args.topic) as recorder:
        recorder.wait_matched(300.0)
        print("recording", flush=True)  # the caller may start the input now
        stop.wait()
        poses = dict(recorder.poses)
    args.out.write_text(json.dumps({str(k): v.tolist() for k, v in poses.items()}))
    print(f"{len(poses)} poses written to {args.out}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
