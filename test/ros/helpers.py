"""In-process rclpy helpers: a per-test Context and a feeder that plays a dataset into the nodes."""

from __future__ import annotations

import dataclasses
import random
import threading
from pathlib import Path

import numpy as np
import rclpy
from geometry_msgs.msg import PoseStamped
from rclpy.context import Context
from rclpy.executors import Executor, MultiThreadedExecutor, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image

from msg_adapters import stamp_to_ns
from sgs_slam_core.datasets import open_dataset
from sgs_slam_core.frame import Frame
from sgs_slam_ros.messages import camera_info_msg, image_msg

FAST = ["tracking.adam.iterations=15", "mapping.iterations=8"]
CAMERA = "camera_color_optical_frame"


def node_params(**extra: object) -> list[Parameter]:
    values = {
        "preset": "synthetic",
        "overrides": FAST,
        "lockstep": True,
        "input_qos": "reliable_all",
        "render_rate_hz": 2.0,
        "points_rate_hz": 2.0,
        "path_rate_hz": 10.0,
        "gaussians_rate_hz": 0.0,
    } | extra
    return [Parameter(k, value=v) for k, v in values.items()]


def new_context(domain_id: int | None = None) -> Context:
    ctx = Context()
    domain = random.randint(1, 100) if domain_id is None else domain_id
    rclpy.init(context=ctx, domain_id=domain, signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    return ctx


def tiny_frames(scene: Path) -> list[Frame]:
    """The tiny scene's frames with depth rounded to millimetres, as a 16UC1 camera delivers them."""
    ds = open_dataset(scene)
    return [
        dataclasses.replace(ds[i], depth=(np.round(ds[i].depth * 1000) / 1000).astype(np.float32))
        for i in range(len(ds))
    ]


def diagnostics_of(arrays: list, node: str) -> list[tuple[int, str, dict[str, str]]]:
    """(level, message, values) of every status of ``node`` in received DiagnosticArrays, oldest first."""
    return [
        (s.level[0] if isinstance(s.level, bytes) else int(s.level), s.message, {kv.key: kv.value for kv in s.values})
        for a in list(arrays)
        for s in a.status
        if s.name.endswith(node)
    ]


class Spinner:
    """An executor spinning the given nodes in a background thread.

    ``threads=1`` is the executor ``ros2 run`` uses (single-threaded); rclpy's multi-threaded one
    busy-polls while a callback group is busy and messages keep arriving, which starves the SLAM
    threads of the GIL under a sustained stream (the soak benchmark).
    """

    def __init__(self, ctx: Context, nodes: list[Node], threads: int = 4) -> None:
        self.executor: Executor = (
            SingleThreadedExecutor(context=ctx)
            if threads == 1
            else MultiThreadedExecutor(num_threads=threads, context=ctx)
        )
        for n in nodes:
            self.executor.add_node(n)
        self._stopping = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        try:
            self.executor.spin()
        except Exception:
            # rclpy may raise InvalidHandle in spin() when shutdown() races a callback; only a
            # failure while running is a test failure.
            if not self._stopping.is_set():
                raise

    def stop(self) -> None:
        self._stopping.set()
        self.executor.shutdown()
        self.thread.join(timeout=5)


class Feeder(Node):
    """Publishes frames like a camera driver and records what the SLAM nodes publish."""

    def __init__(self, ctx: Context, pose_topic: str = "/tracking_node/pose") -> None:
        super().__init__("feeder", context=ctx)
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_ALL)
        self.pubs = {t: self.create_publisher(Image, t, qos) for t in ("/rgb/image", "/depth/image", "/semantic/image")}
        self.info_pub = self.create_publisher(CameraInfo, "/rgb/camera_info", qos)
        self.poses: dict[int, PoseStamped] = {}
        self.pose_sub = self.create_subscription(
            PoseStamped, pose_topic, lambda m: self.poses.__setitem__(stamp_to_ns(m.header.stamp), m), 50
        )

    def connected(self, subscribers: int = 1) -> bool:
        """Whether every camera topic, camera_info included, has ``subscribers`` matched readers (labels: one,
        the node that maps) and the pose topic a matched writer: a message sent before its reader matched
        is lost (volatile QoS)."""
        pubs = [p for name, p in self.pubs.items() if name != "/semantic/image"] + [self.info_pub]
        inputs = all(p.get_subscription_count() >= subscribers for p in pubs)
        labels = self.pubs.get("/semantic/image")
        inputs = inputs and (labels is None or labels.get_subscription_count() >= 1)
        return inputs and self.pose_sub.get_publisher_count() >= 1

    def publish(
        self, frame: Frame, depth_encoding: str = "16UC1", semantic: bool = True, frame_id: str = CAMERA
    ) -> None:
        stamp, cam = frame.stamp_ns, frame_id
        self.info_pub.publish(camera_info_msg(frame.intrinsics, stamp, cam))
        self.pubs["/rgb/image"].publish(image_msg(frame.rgb, "rgb8", stamp, cam))
        depth = (frame.depth * 1000).round().astype("uint16") if depth_encoding == "16UC1" else frame.depth
        self.pubs["/depth/image"].publish(image_msg(depth, depth_encoding, stamp, cam))
        if semantic:
            self.pubs["/semantic/image"].publish(image_msg(frame.labels.astype("uint16"), "16UC1", stamp, cam))


@dataclasses.dataclass
class WatchedSlam:
    """slam_node's nodes, a feeder, what it heard on /diagnostics and /rosout, and the spinner of them all."""

    ctx: Context
    nodes: list
    feeder: Feeder
    diagnostics: list
    logs: list
    spinner: Spinner

    def shut_down(self) -> None:
        shut_down(self.ctx, [*self.nodes, self.feeder], self.spinner)


def watched_slam(params: list[Parameter]) -> WatchedSlam:
    """``build_slam_nodes`` with ``params`` in a new context, fed and watched by a :class:`Feeder`, spinning."""
    from diagnostic_msgs.msg import DiagnosticArray
    from rcl_interfaces.msg import Log

    from sgs_slam_ros.slam_node import build_slam_nodes

    ctx = new_context()
    nodes = build_slam_nodes(context=ctx, parameter_overrides=params)
    feeder = Feeder(ctx)
    diag, logs = [], []
    feeder.create_subscription(DiagnosticArray, "/diagnostics", diag.append, 50)
    feeder.create_subscription(Log, "/rosout", logs.append, 100)
    return WatchedSlam(ctx, nodes, feeder, diag, logs, Spinner(ctx, [*nodes, feeder]))


def shut_down(ctx: Context, nodes: list, spinner: Spinner | None = None) -> None:
    """Stop the spinner, close (where they can) and destroy ``nodes``, and shut ``ctx`` down."""
    if spinner is not None:
        spinner.stop()
    for n in nodes:
        getattr(n, "close", lambda: None)()
        n.destroy_node()
    ctx.try_shutdown()
