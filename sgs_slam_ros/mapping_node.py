"""``mapping_node``: owns the Gaussian map; publishes renders, point clouds and the map itself.

Outputs: ``~/render/color`` (rgb8), ``~/render/semantic`` (rgb8 palette), ``~/render/labels``
(16UC1 ids), ``~/render/depth`` (32FC1 m) from the latest pose; ``~/points`` (PointCloud2 x, y, z,
rgb, label); ``~/gaussians`` (PointCloud2 with every Gaussian field, transient local);
``/diagnostics``. Services: ``~/save_map``, ``~/load_map`` (Trigger, file from ``map_path``),
``~/reset`` (Trigger), ``~/pause`` (SetBool), ``~/apply_edit`` (Trigger: the edit the ``edit.*``
parameters describe) and ``~/undo_edit`` (Trigger: revert the last edit and unlock its classes).
Standalone (``pose_source:=topic``) it subscribes the camera topics and ``tracking_node/pose`` and
maps frames whose stamps match a pose exactly.
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict
from pathlib import Path as FilePath

import numpy as np
import torch
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from std_srvs.srv import SetBool, Trigger

from msg_adapters import AdapterError, gaussians_to_cloud, pack_rgb, pose_to_c2w, stamp_to_ns
from msg_adapters.pointcloud import POINT_DTYPE
from sgs_slam_core.errors import SgsSlamError
from sgs_slam_core.frame import Frame
from sgs_slam_core.live import MapJob, SlamPipeline
from sgs_slam_core.mapio import load_map, save_map
from sgs_slam_core.slam.system import MapOutcome, Slam, TrackOutcome
from sgs_slam_ros.diagnostics import Diagnostics, RateMeter
from sgs_slam_ros.edits import requested_edits
from sgs_slam_ros.frames import FrameAssembler
from sgs_slam_ros.messages import image_msg, pointcloud_msg
from sgs_slam_ros.params import COMMON, EDIT, MAPPING, declare, slam_config
from sgs_slam_ros.qos import input_qos, latched_qos, output_qos
from sgs_slam_ros.runtime import run_nodes

__all__ = ["MappingNode", "main"]

OK, WARN = 0, 1
_PENDING = 64  # frames / poses kept while waiting for their partner (standalone)


class MappingNode(Node):
    """Maps tracked frames (shared pipeline in slam_node, or standalone with poses from a topic)."""

    def __init__(self, pipeline: SlamPipeline | None = None, **kwargs: object) -> None:
        super().__init__("mapping_node", **kwargs)
        self.params = declare(self, COMMON + MAPPING + EDIT)
        self.map_frame = self.params["map_frame"]
        self._owns_pipeline = pipeline is None
        self.mapped_rate = RateMeter()
        self.last_mapped_stamp = -1
        self._render_lock = threading.Lock()
        if pipeline is None:
            pipeline = SlamPipeline(Slam(slam_config(self.params)), self.params["lockstep"], track=False, map=True,
                                    log=self.get_logger().error)  # fmt: skip
            self._subscribe_inputs()
        self.pipeline = pipeline
        pipeline.map_listeners.append(self._on_mapped)
        out = output_qos(2)
        self.color_pub = self.create_publisher(Image, "~/render/color", out)
        self.semantic_pub = self.create_publisher(Image, "~/render/semantic", out)
        self.labels_pub = self.create_publisher(Image, "~/render/labels", out)
        self.depth_pub = self.create_publisher(Image, "~/render/depth", out)
        self.points_pub = self.create_publisher(PointCloud2, "~/points", output_qos(1))
        self.gaussians_pub = self.create_publisher(PointCloud2, "~/gaussians", latched_qos())
        for rate, callback in ((self.params["render_rate_hz"], self.publish_renders),
                               (self.params["points_rate_hz"], self.publish_points),
                               (self.params["gaussians_rate_hz"], self.publish_gaussians)):  # fmt: skip
            if rate > 0:
                self.create_timer(1.0 / rate, callback)
        self.create_service(Trigger, "~/save_map", self._save_map)
        self.create_service(Trigger, "~/load_map", self._load_map)
        self.create_service(Trigger, "~/reset", self._reset)
        self.create_service(SetBool, "~/pause", self._pause)
        self.create_service(Trigger, "~/apply_edit", self._apply_edit)
        self.create_service(Trigger, "~/undo_edit", self._undo_edit)
        self.diagnostics = Diagnostics(self, self._status)

    # ------------------------------------------------------------------ standalone inputs
    def _subscribe_inputs(self) -> None:
        self.assembler = FrameAssembler(
            self.params["use_semantics"], self.params["sync_queue_size"], round(self.params["sync_slop_s"] * 1e9),
            self.params["depth_scale"], self._on_frame, self.get_logger().warn,
        )  # fmt: skip
        qos = input_qos(self.params["input_qos"], self.params["sync_queue_size"])
        topics = ["rgb/image", "depth/image", *(["semantic/image"] if self.params["use_semantics"] else [])]
        for i, topic in enumerate(topics):
            self.create_subscription(Image, topic, lambda msg, i=i: self.assembler.image(i, msg), qos)
        self.create_subscription(CameraInfo, "rgb/camera_info", self.assembler.camera_info, qos)
        self.create_subscription(PoseStamped, "tracking_node/pose", self._on_pose, output_qos(50))
        self._frames: OrderedDict[int, Frame] = OrderedDict()
        self._poses: OrderedDict[int, np.ndarray] = OrderedDict()
        self._pair_lock = threading.Lock()

    def _on_frame(self, frame: Frame) -> None:
        with self._pair_lock:
            self._frames[frame.stamp_ns] = frame
            self._pair()

    def _on_pose(self, msg: PoseStamped) -> None:
        try:
            c2w = pose_to_c2w(msg)
        except AdapterError as err:
            self.assembler.reject("bad pose", str(err))
            return
        with self._pair_lock:
            self._poses[stamp_to_ns(msg.header.stamp)] = c2w
            self._pair()

    def _pair(self) -> None:
        for stamp in [s for s in self._frames if s in self._poses]:
            self.pipeline.submit_job(MapJob(self._frames.pop(stamp), c2w=self._poses.pop(stamp)))
        for queue in (self._frames, self._poses):
            while len(queue) > _PENDING:
                queue.popitem(last=False)
                self.pipeline.stats.dropped_frames += 1

    # ------------------------------------------------------------------ outputs
    def _on_mapped(self, frame: Frame, tracked: TrackOutcome, result: MapOutcome) -> None:
        if not self.context.ok():  # shutting down: the publishers are gone
            return
        self.mapped_rate.tick()
        self.last_mapped_stamp = tracked.stamp_ns
        if self.params["lockstep"]:
            self.publish_gaussians()  # a tracker in another process waits for this map

    def _latest_pose(self) -> tuple[int, np.ndarray] | None:
        trajectory = self.pipeline.slam.trajectory
        return (trajectory[-1][1], trajectory[-1][2]) if trajectory else None

    def publish_renders(self) -> None:
        """Render the map from the latest pose and publish colour, semantics, labels and depth."""
        slam, latest = self.pipeline.slam, self._latest_pose()
        if latest is None or slam.num_gaussians == 0 or slam.intrinsics is None:
            return
        stamp, c2w = latest
        with self._render_lock, torch.no_grad():
            out = slam.render_view(c2w)
            color = (out.color.clamp(0, 1) * 255).round().to(torch.uint8).cpu().numpy()
            labels = (
                slam.decode(out.semantic).cpu().numpy() if out.semantic.shape[-1] else np.zeros(color.shape[:2], int)
            )
            labels = np.where(out.silhouette.cpu().numpy() > 0.5, labels, 0)
            depth = out.depth.cpu().numpy().astype(np.float32)
        frame_id = "camera_color_optical_frame"
        self.color_pub.publish(image_msg(color, "rgb8", stamp, frame_id))
        self.semantic_pub.publish(image_msg(slam.codec.table.colorize(labels), "rgb8", stamp, frame_id))
        self.labels_pub.publish(image_msg(labels.astype(np.uint16), "16UC1", stamp, frame_id))
        self.depth_pub.publish(image_msg(depth, "32FC1", stamp, frame_id))

    def points(self) -> np.ndarray:
        """The map as coloured, labelled points (every Gaussian centre, subsampled to ``points_max``)."""
        g = self.pipeline.slam.gaussians.detach().to("cpu")
        step = max(1, int(np.ceil(len(g) / self.params["points_max"])))
        pts = np.zeros(len(range(0, len(g), step)), dtype=POINT_DTYPE)
        means = g.means[::step].float().numpy()
        pts["x"], pts["y"], pts["z"] = means.T
        pts["rgb"] = pack_rgb((g.colors[::step].clamp(0, 1) * 255).round().to(torch.uint8).numpy())
        pts["label"] = g.labels[::step].numpy().astype(np.uint32)
        return pts

    def publish_points(self) -> None:
        """Publish ``~/points``."""
        if self.pipeline.slam.num_gaussians:
            self.points_pub.publish(pointcloud_msg(self.points(), self._stamp(), self.map_frame))

    def publish_gaussians(self) -> None:
        """Publish the whole map on ``~/gaussians`` (stamp = the last mapped frame)."""
        if self.pipeline.slam.num_gaussians:
            cloud = gaussians_to_cloud(self.pipeline.slam.gaussians)
            self.gaussians_pub.publish(pointcloud_msg(cloud, max(self.last_mapped_stamp, 0), self.map_frame))

    def _stamp(self) -> int:
        latest = self._latest_pose()
        return latest[0] if latest else self.get_clock().now().nanoseconds

    # ------------------------------------------------------------------ services
    def _save_map(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        path = FilePath(self.get_parameter("map_path").value)
        try:
            with self.pipeline.exclusive():
                m = self.pipeline.slam.to_map_file()
                save_map(path, m)
            response.success, response.message = True, f"saved {len(m.gaussians)} Gaussians to {path}"
        except (OSError, SgsSlamError, TimeoutError) as err:
            response.success, response.message = False, f"cannot save {path}: {err}"
        return response

    def _load_map(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        path = FilePath(self.get_parameter("map_path").value)
        try:
            saved = load_map(path, self.pipeline.slam.device)
            with self.pipeline.exclusive():
                self.pipeline.slam.load_map(saved)
            if getattr(self, "assembler", None):
                self.assembler.reset()
            self.publish_gaussians()
            response.success, response.message = True, f"loaded {len(saved.gaussians)} Gaussians from {path}"
        except (OSError, SgsSlamError, TimeoutError) as err:
            response.success, response.message = False, f"cannot load {path}: {err}"
        return response

    def _apply_edit(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        done = []
        try:
            edits = requested_edits(self)
            with self.pipeline.exclusive():
                for edit in edits:
                    done.append(self.pipeline.slam.apply_edit(edit).summary())
            response.success = True
        except (SgsSlamError, TimeoutError) as err:
            response.success = False
            done.append(f"edit refused: {err}")
        response.message = "; ".join(done)
        self._after_edit(response)
        return response

    def _undo_edit(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        try:
            with self.pipeline.exclusive():
                record = self.pipeline.slam.undo_edit()
            response.success, response.message = True, f"undone {record.summary()}"
        except (SgsSlamError, TimeoutError) as err:
            response.success, response.message = False, f"cannot undo: {err}"
        self._after_edit(response)
        return response

    def _after_edit(self, response: Trigger.Response) -> None:
        if response.success:
            self.get_logger().info(response.message)
        else:
            self.get_logger().warn(response.message)
        self.publish_gaussians()  # the edited map, right away
        self.publish_points()
        self.publish_renders()

    def _reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        response.success = self.pipeline.reset()
        if getattr(self, "assembler", None):
            self.assembler.reset()
        self.last_mapped_stamp = -1
        response.message = "map cleared" if response.success else "timed out waiting for the workers"
        return response

    def _pause(self, request: SetBool.Request, response: SetBool.Response) -> SetBool.Response:
        self.pipeline.pause(bool(request.data))
        response.success, response.message = True, "paused" if request.data else "running"
        return response

    def _status(self) -> tuple[int, str, dict[str, str]]:
        st = self.pipeline.stats
        level, message = OK, "paused" if self.pipeline.paused else "mapping"
        if st.errors:
            level, message = WARN, f"errors: {st.last_error}"
        values = {
            "processing_rate_hz": f"{self.mapped_rate.rate():.2f}",
            "frames_mapped": str(st.mapped),
            "queue_drops": str(st.dropped_jobs + st.dropped_frames),
            "gaussians": str(self.pipeline.slam.num_gaussians),
            "keyframes": str(len(self.pipeline.slam.keyframes)),
            "tracking_failures": str(st.tracking_failures),
            "locked_classes": " ".join(str(i) for i in sorted(self.pipeline.slam.locked_labels)) or "none",
            "undoable_edits": str(self.pipeline.slam.edits.depth),
        }
        assembler = getattr(self, "assembler", None)
        if assembler is not None:
            values["dropped_bad_input"] = str(sum(assembler.rejected.values()))
            idle = time.monotonic() - self.mapped_rate.last if self.mapped_rate.last else None
            if idle is None or idle > self.params["stale_input_s"]:
                level, message = WARN, "no frame mapped recently: waiting for images and tracking_node/pose"
        return level, message, values

    def close(self) -> None:
        """Stop the workers this node owns."""
        if self._owns_pipeline:
            self.pipeline.shutdown()


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run sgs_slam_ros mapping_node`` (standalone, poses from tracking_node)."""
    return run_nodes(lambda: [MappingNode()], args)


if __name__ == "__main__":
    raise SystemExit(main())
