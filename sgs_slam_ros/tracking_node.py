"""``tracking_node``: synchronises the camera topics and publishes the camera pose and path.

Inputs (relative, remappable): ``rgb/image``, ``depth/image``, ``semantic/image`` (with
``use_semantics``), ``rgb/camera_info``; standalone with ``map_source:=topic`` it also follows
``mapping_node/gaussians``. Outputs: ``~/pose`` (PoseStamped in ``map_frame``), ``~/path``,
``/diagnostics``; service ``~/reset`` (Trigger).
"""

from __future__ import annotations

import threading
import time

from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from std_srvs.srv import Trigger

from msg_adapters import AdapterError, gaussians_from_cloud, pointcloud_to_numpy, stamp_to_ns
from sgs_slam_core.errors import SgsSlamError
from sgs_slam_core.frame import Frame
from sgs_slam_core.live import SlamPipeline
from sgs_slam_core.slam.system import Slam, TrackOutcome
from sgs_slam_ros.diagnostics import Diagnostics, RateMeter
from sgs_slam_ros.frames import FrameAssembler
from sgs_slam_ros.messages import path_msg, pose_msg
from sgs_slam_ros.params import COMMON, TRACKING, declare, slam_config
from sgs_slam_ros.qos import input_qos, latched_qos, output_qos
from sgs_slam_ros.runtime import run_nodes

__all__ = ["TrackingNode", "main"]

_REPUBLISH_S = 1.0  # s: lockstep with a remote mapper re-sends the last pose this often while waiting for its map

OK, WARN, ERROR = 0, 1, 2


class TrackingNode(Node):
    """Tracks every synchronised frame (shared pipeline in slam_node, or standalone)."""

    def __init__(self, standalone: bool = True, **kwargs: object) -> None:
        """Declare parameters, publishers and subscriptions.

        ``standalone``: track only and follow ``mapping_node/gaussians``; else own the full pipeline
        (tracking and mapping threads) that a :class:`MappingNode` in the same process shares.
        """
        super().__init__("tracking_node", **kwargs)
        self.params = declare(self, COMMON + TRACKING)
        self.map_frame = self.params["map_frame"]
        self._remote_map_stamp = -1
        self._last_pose_sent = time.monotonic()
        slam = Slam(slam_config(self.params))
        log = self.get_logger().error
        if standalone:
            if self.params["map_source"] != "topic":
                self.get_logger().warn("standalone tracking_node follows mapping_node/gaussians (map_source:=topic)")
            pipeline = SlamPipeline(slam, self.params["lockstep"], track=True, map=False, log=log,
                                    ready_to_track=self._remote_map_ready)  # fmt: skip
            self.create_subscription(PointCloud2, "mapping_node/gaussians", self._on_gaussians, latched_qos())
        else:
            pipeline = SlamPipeline(slam, self.params["lockstep"], track=True, map=True, log=log)
        self.pipeline = pipeline
        pipeline.pose_listeners.append(self._on_pose)
        self.inputs = RateMeter()
        self.outputs = RateMeter()
        self.assembler = FrameAssembler(
            self.params["use_semantics"], self.params["sync_queue_size"], round(self.params["sync_slop_s"] * 1e9),
            self.params["depth_scale"], self._on_frame, self.get_logger().warn,
        )  # fmt: skip
        qos = input_qos(self.params["input_qos"], self.params["sync_queue_size"])
        self.topics = ["rgb/image", "depth/image", *(["semantic/image"] if self.params["use_semantics"] else [])]
        for i, topic in enumerate(self.topics):
            self.create_subscription(Image, topic, lambda msg, i=i: self._image(i, msg), qos)
        self.create_subscription(CameraInfo, "rgb/camera_info", self.assembler.camera_info, qos)
        self.pose_pub = self.create_publisher(PoseStamped, "~/pose", output_qos(10))
        self.path_pub = self.create_publisher(Path, "~/path", output_qos(1))
        self.path: list[PoseStamped] = []
        self._path_lock = threading.Lock()
        self.create_service(Trigger, "~/reset", self._reset)
        self.diagnostics = Diagnostics(self, self._status)
        topics = ", ".join(self.resolve_topic_name(t) for t in self.topics)
        mode = "lockstep" if self.params["lockstep"] else "live"
        self.get_logger().info(
            f"tracking {topics} with preset {self.params['preset']} on {pipeline.slam.device} ({mode})"
        )

    # ------------------------------------------------------------------ inputs
    def _image(self, index: int, msg: Image) -> None:
        if index == 0:
            self.inputs.tick()
        self.assembler.image(index, msg)

    def _on_frame(self, frame: Frame) -> None:
        self.pipeline.submit_frame(frame, time.monotonic())

    def _on_gaussians(self, msg: PointCloud2) -> None:
        try:
            gaussians = gaussians_from_cloud(pointcloud_to_numpy(msg))
            self.pipeline.slam.set_map(gaussians)
        except (AdapterError, SgsSlamError) as err:
            self.assembler.reject("bad map message", str(err))
            return
        self._remote_map_stamp = stamp_to_ns(msg.header.stamp)
        self.pipeline.wake()

    def _remote_map_ready(self, frames_tracked: int) -> bool:
        """Lockstep across processes: the mapper's map must include the last tracked frame.

        Polled (every 0.5 s at most) while a frame waits. The last pose is then published again once
        a second: a mapper whose subscription was matched only after the first publication (DDS
        discovery under load) would otherwise never map that frame, and both nodes would wait forever.
        """
        trajectory = self.pipeline.slam.trajectory
        ready = frames_tracked == 0 or self._remote_map_stamp >= trajectory[-1][1]
        now = time.monotonic()
        if not ready and now - self._last_pose_sent >= _REPUBLISH_S:
            with self._path_lock:
                last = self.path[-1] if self.path else None
            if last is not None:
                self.pose_pub.publish(last)
                self._last_pose_sent = now
        return ready

    # ------------------------------------------------------------------ outputs
    def _on_pose(self, frame: Frame, outcome: TrackOutcome) -> None:
        if not self.context.ok():  # shutting down: the publishers are gone
            return
        msg = pose_msg(outcome.c2w, outcome.stamp_ns, self.map_frame)
        self.pose_pub.publish(msg)
        self._last_pose_sent = time.monotonic()
        self.outputs.tick()
        with self._path_lock:
            self.path.append(msg)
            del self.path[: -self.params["path_max_length"]]
            path = list(self.path)
        self.path_pub.publish(path_msg(path, outcome.stamp_ns, self.map_frame))
        if outcome.failed:
            self.get_logger().warn(f"tracking failure at stamp {outcome.stamp_ns}: {outcome.failure_reason}")

    def _reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        response.success = self.pipeline.reset()
        self.assembler.reset()
        with self._path_lock:
            self.path.clear()
        response.message = "map and trajectory cleared" if response.success else "timed out waiting for the workers"
        return response

    def _status(self) -> tuple[int, str, dict[str, str]]:
        st, a = self.pipeline.stats, self.assembler
        idle = self.inputs.idle_s()
        level, message = OK, "tracking"
        if idle is None or idle > self.params["stale_input_s"]:
            level = WARN
            waited = "never" if idle is None else f"for {idle:.0f} s"
            message = f"no input {waited}: waiting for {', '.join(self.resolve_topic_name(t) for t in self.topics)}"
        elif self.pipeline.paused:
            message = "paused"
        elif st.errors:
            level, message = WARN, f"errors: {st.last_error}"
        latency = sorted(st.latency_s)
        values = {
            "input_rate_hz": f"{self.inputs.rate():.2f}",
            "processing_rate_hz": f"{self.outputs.rate():.2f}",
            "latency_ms": f"{1e3 * latency[len(latency) // 2]:.1f}" if latency else "n/a",
            "frames_in": str(st.frames_in),
            "frames_tracked": str(st.tracked),
            "queue_drops": str(st.dropped_frames + a.sync.dropped),
            "tracking_failures": str(st.tracking_failures),
            "gaussians": str(self.pipeline.slam.num_gaussians),
            "dropped_bad_input": str(sum(a.rejected.values())),
            **{f"dropped[{cause}]": str(n) for cause, n in a.rejected.items()},
        }
        return level, message, values

    def close(self) -> None:
        """Stop the workers (this node owns the pipeline)."""
        self.pipeline.shutdown()


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run sgs_slam_ros tracking_node`` (standalone, follows a mapping node)."""
    return run_nodes(lambda: [TrackingNode()], args)


if __name__ == "__main__":
    raise SystemExit(main())
