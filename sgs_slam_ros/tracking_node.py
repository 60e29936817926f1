"""``tracking_node``: synchronises the camera topics and publishes the camera pose, path and /tf.

Inputs (relative, remappable): ``rgb/image``, ``depth/image``, ``semantic/image`` (with
``use_semantics``), ``rgb/camera_info``; standalone with ``map_source:=topic`` it also follows
``mapping_node/gaussians``. Outputs: ``~/pose`` (PoseStamped in ``map_frame``), ``~/path``,
``/tf`` + ``/tf_static`` (``map -> camera``, or ``map [-> odom] -> base_frame -> camera``),
``/diagnostics``; with ``forward_frames`` the accepted frames at the processing size on
``~/frames/*`` (:mod:`sgs_slam_ros.forward`); service ``~/reset`` (Trigger). The map frame is z-up
by default (``map_alignment``).
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable

import numpy as np
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path
from rclpy.node import Node
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import String
from std_srvs.srv import Trigger

from msg_adapters import AdapterError, gaussians_from_cloud, pointcloud_to_numpy, stamp_to_ns
from sgs_slam_core.errors import SgsSlamError
from sgs_slam_core.frame import Frame
from sgs_slam_core.frame_ids import CAMERA_FRAME
from sgs_slam_core.geometry.gravity import MapAlignment, pose_from_xyz_rpy
from sgs_slam_core.labels import LabelError, LabelTable
from sgs_slam_core.live import SlamPipeline
from sgs_slam_core.slam.guard import TrackingState
from sgs_slam_core.slam.map_frame import MapFrameChoice
from sgs_slam_core.slam.outcomes import TrackOutcome
from sgs_slam_core.slam.system import Slam
from sgs_slam_ros.activity import Activity
from sgs_slam_ros.camera_inputs import CameraInputs
from sgs_slam_ros.diagnostics import OK, WARN, Diagnostics, RateMeter
from sgs_slam_ros.forward import FrameForwarder
from sgs_slam_ros.frames import AUTO_DOWNSCALE
from sgs_slam_ros.messages import path_msg, pose_msg
from sgs_slam_ros.params import COMMON, TRACKING, ParameterError, declare, slam_config, use_threads
from sgs_slam_ros.qos import latched_qos, output_qos
from sgs_slam_ros.runtime import run_nodes
from sgs_slam_ros.tf import TfFrames, TfPublisher
from sgs_slam_ros.timers import Throttled

__all__ = ["TrackingNode", "main"]

_REPUBLISH_S = 1.0  # s: lockstep with a remote mapper re-sends the last pose this often while waiting for its map


SILENT_HINTS = {
    "semantic": "no labels, so the map has no classes: run segmentation_node, remap semantic/image, or set "
    "use_semantics:=false",
    "camera_info": "remap rgb/camera_info to the colour camera's camera_info",
    "depth": "remap depth/image to the depth image registered to colour (e.g. aligned_depth_to_color/image_raw)",
}


class TrackingNode(Node):
    """Tracks every synchronised frame (shared pipeline in slam_node, or standalone)."""

    def __init__(self, standalone: bool = True, **kwargs: object) -> None:
        """Declare parameters, publishers and subscriptions.

        ``standalone``: track only and follow ``mapping_node/gaussians``; else own the full pipeline
        (tracking and mapping threads) that a :class:`MappingNode` in the same process shares.
        """
        super().__init__("tracking_node", **kwargs)
        self.params = declare(self, COMMON + TRACKING)
        use_threads(self.params)
        self.map_frame = self.params["map_frame"]
        try:
            self.mount = pose_from_xyz_rpy(self.params["camera_mount"])
        except SgsSlamError as err:
            raise ParameterError(f"parameter camera_mount: {err}") from err
        self.alignment = MapAlignment(self.params["map_alignment"])
        self.alignment_used = ""  # what the first frame of this run chose ("mount (no floor in view)", ...)
        self._remote_map_stamp = -1
        self._last_pose_sent = time.monotonic()
        self.reset_listeners: list[Callable[[], None]] = []  # e.g. the composed mapping node's outputs
        self._standalone = standalone
        forward = self.params["forward_frames"]
        self.forwarder = FrameForwarder(self, self.params["use_semantics"]) if forward else None
        self._forwarded_pose: PoseStamped | None = None  # the pose of the last frame forwarded
        self.pipeline = pipeline = self._pipeline(standalone)
        self._compile_pending = pipeline.slam.config.render.compile  # traced on the first frame
        self.activity = Activity(pipeline.idle)
        pipeline.pose_listeners.append(self._on_pose)
        pipeline.map_listeners.append(lambda *_: self.activity.end())
        self.outputs = RateMeter()
        on_labels = None if standalone and not forward else self._on_labels  # a standalone tracker maps nothing
        self.camera = CameraInputs(
            self, self.params, self._on_frame, self.activity, hints=SILENT_HINTS, on_labels=on_labels
        )
        self.assembler = self.camera.assembler
        if self.params["use_semantics"] and not standalone:  # a label source (segmentation_node) names its ids' table
            self.create_subscription(String, "semantic/label_table", self._on_label_table, latched_qos())
        self.pose_pub = self.create_publisher(PoseStamped, "~/pose", output_qos(10))
        self.path_pub = self.create_publisher(Path, "~/path", output_qos(1))
        self.tf = TfPublisher(
            self,
            TfFrames(
                self.map_frame,
                self.params["base_frame"],
                self.params["odom_frame"],
                self.mount,
                self.params["publish_camera_mount"],
            ),
            self.get_logger().warn,
        )
        self.path: list[PoseStamped] = []
        self._path_lock = threading.Lock()
        self._state: TrackingState = "ok"  # of the last pose published
        # on the executor at a bounded rate, not per pose on the tracking thread: a Path costs time
        # linear in its length to publish, and a live run's path grows by the camera's rate
        self.path_out = Throttled(self, self.params["path_rate_hz"], self._publish_path)
        self.params.on_change["path_rate_hz"] = self.path_out.set_rate
        self.create_service(Trigger, "~/reset", self._reset)
        self.diagnostics = Diagnostics(self, self._status)
        self._log_start(pipeline)

    def _log_start(self, pipeline: SlamPipeline) -> None:
        """One line: the inputs, preset, device, mode, tracker, processing size and map frame."""
        mode = "lockstep" if self.params["lockstep"] else "live"
        factor = self.params["downscale"]
        size = {1.0: "input size", AUTO_DOWNSCALE: f"auto size ({self.camera.assembler.auto_text()})"}.get(
            factor, f"input size / {factor:g}"
        )
        self.get_logger().info(
            f"tracking {', '.join(self.camera.watch.topics.values())} with preset {self.params['preset']} "
            f"on {pipeline.slam.device} ({mode}, {pipeline.slam.config.tracking.method} tracker, "
            f"processing at {size}); map frame '{self.map_frame}' ({self.alignment.value})"
        )

    def _pipeline(self, standalone: bool) -> SlamPipeline:
        """The SLAM and its workers: tracking and mapping here, or tracking against a mapper's map."""
        slam = Slam(slam_config(self.params))
        slam.prepare(self.get_logger().info)  # compile the CPU kernels now, not inside the first frame
        log = self.get_logger().error
        if not standalone:
            late_labels = self.params["use_semantics"]
            return SlamPipeline(slam, self.params["lockstep"], track=True, map=True, log=log, late_labels=late_labels)
        if self.params["map_source"] != "topic":
            self.get_logger().warn("standalone tracking_node follows mapping_node/gaussians (map_source:=topic)")
        self.create_subscription(PointCloud2, "mapping_node/gaussians", self._on_gaussians, latched_qos())
        return SlamPipeline(
            slam, self.params["lockstep"], track=True, map=False, log=log, ready_to_track=self._remote_map_ready
        )

    # ------------------------------------------------------------------ inputs
    def _on_frame(self, frame: Frame) -> None:
        if self._compile_pending:
            # render.compile: the graphs are traced at the camera's size on the first frame, which is
            # left out; traced at first use, frame after frame would wait seconds as the camera moved on
            self._compile_pending = False
            self.pipeline.slam.prepare(self.get_logger().info, frame)
            return
        self.activity.begin()
        self.pipeline.submit_frame(frame, time.monotonic())

    def _on_labels(self, stamp_ns: int, labels: np.ndarray) -> None:
        if not self._standalone:
            self.pipeline.submit_labels(stamp_ns, labels, time.monotonic())
        if self.forwarder is not None:
            self.forwarder.labels(stamp_ns, labels, self.camera_frame())

    def _report_map_frame(self, choice: MapFrameChoice) -> None:
        """Say how the run's first frame set the map frame (``map_alignment``), as /diagnostics will."""
        self.alignment_used = choice.alignment
        log = self.get_logger()
        if self.alignment is MapAlignment.FLOOR and choice.floor is None:
            log.warn(
                "no floor plane in the first frame: map_alignment falls back to 'mount' (the z-up map assumes "
                "camera_mount, a level camera); /diagnostics says map_alignment: mount"
            )
        elif choice.floor is not None:
            up = self.mount[:3, :3].T @ [0.0, 0.0, 1.0]
            log.info(
                f"map frame levelled on the floor: camera {choice.floor.height_m:.2f} m above it, tilted "
                f"{choice.floor.tilt_deg(up):.1f} deg from camera_mount "
                f"({100 * choice.floor.inlier_fraction:.0f} % of the pixels)"
            )

    def _on_label_table(self, msg: String) -> None:
        """Use the label source's table when the map is still empty; say so when it differs later."""
        log = self.get_logger()
        try:
            table = LabelTable.from_dict(json.loads(msg.data))
        except (ValueError, LabelError) as err:
            self.assembler.reject("bad label table", str(err))
            return
        if table == self.pipeline.snapshot().codec.table:
            log.info(f"label source's table '{table.name}' ({len(table)} classes) is the map's")
            return
        try:
            used = self.pipeline.use_label_table(table)
        except TimeoutError:
            used = False  # the workers stayed busy: frames are being processed, so the map's table stays
        if used:
            log.info(f"labels: using the label source's table '{table.name}' ({len(table)} classes)")
        else:
            log.warn(f"the label source's table '{table.name}' differs from the map's; call ~/reset to use it")

    def _on_gaussians(self, msg: PointCloud2) -> None:
        try:
            gaussians = gaussians_from_cloud(pointcloud_to_numpy(msg))
            self.pipeline.replace_map(gaussians)
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
        With ``forward_frames`` the mapper maps only the forwarded frames (not failed ones): the last
        of those is the one to wait for, and it is sent again with its pose.
        """
        forwarder = self.forwarder
        last = self.pipeline.snapshot().last_stamp_ns if forwarder is None else forwarder.last_stamp_ns
        ready = frames_tracked == 0 or last is None or self._remote_map_stamp >= last
        now = time.monotonic()
        if not ready and now - self._last_pose_sent >= _REPUBLISH_S:
            with self._path_lock:
                pose = self.path[-1] if self.path else None
            if forwarder is not None:
                forwarder.republish()
                pose = self._forwarded_pose
            if pose is not None:
                self.pose_pub.publish(pose)
                self._last_pose_sent = now
        return ready

    # ------------------------------------------------------------------ outputs
    def camera_frame(self) -> str:
        """Frame id of the camera: the parameter, else the colour images' header, else the realsense default."""
        return self.params["camera_frame"] or self.assembler.frame_id or CAMERA_FRAME

    def _on_pose(self, frame: Frame, outcome: TrackOutcome) -> None:
        if not self.context.ok():  # shutting down: the publishers are gone
            return
        if outcome.map_frame is not None:
            self._report_map_frame(outcome.map_frame)
        msg = pose_msg(outcome.c2w, outcome.stamp_ns, self.map_frame)
        if self.forwarder is not None and not outcome.failed:  # the mapper pairs it with its pose by stamp
            self.forwarder.frame(frame, self.camera_frame())
            self._forwarded_pose = msg
        self.pose_pub.publish(msg)  # while lost: the last tracked pose again (a lockstep player waits for each)
        self.activity.end()
        self._last_pose_sent = time.monotonic()
        self.outputs.tick()
        self._report_state(outcome)
        if outcome.lost:  # no estimate: /tf and the path keep the last tracked pose
            return
        if self.params["publish_tf"]:
            self.tf.publish(outcome.c2w, outcome.stamp_ns, self.camera_frame())
        with self._path_lock:
            self.path.append(msg)
            del self.path[: -self.params["path_max_length"]]
        self.path_out.mark()

    def _report_state(self, outcome: TrackOutcome) -> None:
        """Log tracking failures, and when the camera is lost and found again."""
        log = self.get_logger()
        if outcome.state == "relocalized":
            log.info(f"relocalized at stamp {outcome.stamp_ns}: tracking and mapping go on in the same map")
        elif outcome.lost and self._state != "lost":
            log.warn(f"camera lost at stamp {outcome.stamp_ns} ({outcome.failure_reason}): not mapping, relocalizing")
        elif outcome.failed and not outcome.lost:
            log.warn(f"tracking failure at stamp {outcome.stamp_ns}: {outcome.failure_reason}")
        self._state = outcome.state

    def _publish_path(self) -> bool:
        """Publish ~/path (the kept poses, stamped as the newest); False when it is empty."""
        with self._path_lock:
            path = list(self.path)
        if not path:
            return False
        self.path_pub.publish(path_msg(path, stamp_to_ns(path[-1].header.stamp), self.map_frame))
        return True

    def _reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        response.success = self.pipeline.reset()
        self.after_reset()
        for listener in self.reset_listeners:
            listener()
        response.message = "map and trajectory cleared" if response.success else "timed out waiting for the workers"
        self.get_logger().info(f"~/reset: {response.message}")
        return response

    def after_reset(self) -> None:
        """Forget this node's per-run state (the pipeline was reset)."""
        self.camera.reset()
        self.alignment_used = ""
        self._state = "ok"
        if self.forwarder is not None:
            self.forwarder.reset()
            self._forwarded_pose = None
        with self._path_lock:
            self.path.clear()

    def _status(self) -> tuple[int, str, dict[str, str]]:
        st, a = self.pipeline.stats, self.assembler
        level, message = OK, "tracking" if st.tracked else "waiting for the first synchronised frame"
        silent, warning = self.camera.silence(self.params["stale_input_s"], "no frames")
        if warning is not None:
            level, message = warning
        elif self.pipeline.paused:
            message = "paused"
        elif st.tracking_state == "lost":
            level, message = WARN, "camera lost: relocalizing against the keyframes, not mapping"
        elif st.errors:
            level, message = WARN, f"errors: {st.last_error}"
        latency = sorted(st.latency_s)
        tf_state = "on" if self.params["publish_tf"] and self.tf.available else "off"
        values = {
            "input_rate_hz": f"{self.camera.colour_rate.rate():.2f}",
            "processing_rate_hz": f"{self.outputs.rate():.2f}",
            "latency_ms": f"{1e3 * latency[len(latency) // 2]:.1f}" if latency else "n/a",
            **self.camera.counts(st.dropped_frames),
            **self.camera.sizes(),
            **self.camera.transport(),
            "frames_tracked": str(st.tracked),
            "tracking_failures": str(st.tracking_failures),
            "tracking_state": st.tracking_state,
            "tracking_lost_events": str(st.lost_events),
            "relocalizations": str(st.relocalizations),
            "frames_while_lost": str(st.frames_while_lost),
            "gaussians": str(len(self.pipeline.snapshot().gaussians)),
            **(self.forwarder.counts() if self.forwarder is not None else {}),
            "silent_inputs": self.camera.silent_names(silent),
            "tf": tf_state if self.tf.available else "off (tf2_msgs missing)",
            "map_alignment": self.alignment_used or f"{self.alignment.value} (chosen at the first frame)",
            **{f"dropped[{cause}]": str(n) for cause, n in a.rejected.items()},
        }
        return level, message, values

    def close(self) -> None:
        """Stop the workers (this node owns the pipeline) and log the run's frame counts."""
        self.pipeline.shutdown()
        st = self.pipeline.stats
        counts = self.camera.counts(st.dropped_frames)
        counts["frames_tracked"] = str(st.tracked)
        counts["tracking_failures"] = str(st.tracking_failures)
        counts["tracking_ms_per_frame"] = f"{st.tracking_ms_per_frame:.1f}"
        if self.forwarder is not None:
            counts.update(self.forwarder.counts())
        if self.pipeline.map_enabled:  # slam_node: this process maps too
            counts["frames_mapped"] = str(st.mapped)
            counts["mapping_steps_per_frame"] = f"{st.map_steps_per_frame:.1f}"
            if self.params["use_semantics"]:
                counts["labels_in"] = str(st.labels.labels_in)
                counts["labels_fused"] = str(st.labels.labels_fused)
                counts["labels_unmatched"] = str(st.labels.labels_unmatched)
        self.get_logger().info("final counts: " + ", ".join(f"{k} {v}" for k, v in counts.items()))


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run sgs_slam_ros tracking_node`` (standalone, follows a mapping node)."""
    return run_nodes(lambda: [TrackingNode()], args)


if __name__ == "__main__":
    raise SystemExit(main())
