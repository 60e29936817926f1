"""``mapping_node``: owns the Gaussian map; publishes renders, point clouds and the map itself.

Outputs, each published after new work (a mapped frame, an edit, a load) and at most at its rate:
``~/render/color`` (rgb8), ``~/render/semantic`` (rgb8 palette), ``~/render/labels`` (16UC1 ids),
``~/render/depth`` (32FC1 m), rendered at the pose of the newest mapped frame with its stamp and
camera frame id, at the processing size (``downscale``), which ``~/render/camera_info`` describes;
``~/points`` (PointCloud2 x, y, z, rgb, label) and ``~/gaussians`` (PointCloud2 with every Gaussian
field), both transient local (latched); ``/diagnostics``. Services:
``~/save_map``, ``~/load_map`` (Trigger, file from ``map_path``), ``~/reset`` (Trigger: also
publishes the empty map), ``~/pause`` (SetBool), ``~/apply_edit`` (Trigger: the edit the ``edit.*``
parameters describe) and ``~/undo_edit`` (Trigger: revert the last edit and unlock its classes).
Standalone (``pose_source:=topic``) it subscribes the camera topics (or, with
``frame_source:=tracking_node``, the frames the tracker forwards at the processing size) and
``tracking_node/pose``, and maps frames whose stamps match a pose exactly.

The map outlives the process: autosaves every ``autosave_period_s`` (written in turns with tracking), a
save when the process is stopped (``save_on_shutdown``, from :meth:`MappingNode.finish`), and a map
loaded at start (``load_map_on_start``) in which the camera is relocalized before mapping goes on.
A loaded map (at start or by ``~/load_map``) is relocalized in the same way.
"""

from __future__ import annotations

import os
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from pathlib import Path as FilePath
from typing import NamedTuple

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
from sgs_slam_core.frame_ids import CAMERA_FRAME
from sgs_slam_core.live import MapJob, PipelineStats, SlamPipeline
from sgs_slam_core.live.map_saver import MapSaver, SaveStats
from sgs_slam_core.mapio import MapFile, load_map
from sgs_slam_core.slam.footprint import footprint
from sgs_slam_core.slam.system import MapOutcome, Slam, TrackOutcome
from sgs_slam_ros.activity import Activity
from sgs_slam_ros.camera_inputs import CameraInputs
from sgs_slam_ros.diagnostics import OK, WARN, Diagnostics, RateMeter
from sgs_slam_ros.edits import requested_edits
from sgs_slam_ros.messages import camera_info_msg, image_msg, pointcloud_msg
from sgs_slam_ros.params import COMMON, EDIT, MAPPING, declare, slam_config, use_threads
from sgs_slam_ros.qos import latched_qos, output_qos
from sgs_slam_ros.runtime import run_nodes
from sgs_slam_ros.timers import Throttled

__all__ = ["MappingNode", "main"]

_PENDING = 64  # frames / poses kept while waiting for their partner (standalone)
_FINISH_S = 60.0  # at shutdown: how long the frames in hand may take before the map is saved


def map_file_path(value: str) -> FilePath:
    """The ``map_path`` parameter as a path: '' is ``$ROS_HOME/sgs_slam/map.sgsmap`` (ROS_HOME: ~/.ros)."""
    if value:
        return FilePath(value).expanduser()
    return FilePath(os.environ.get("ROS_HOME") or "~/.ros").expanduser() / "sgs_slam" / "map.sgsmap"


class _View(NamedTuple):
    """What the renders show: the newest mapped frame's pose, stamp and camera frame."""

    stamp_ns: int
    c2w: np.ndarray  # [4, 4]
    frame_id: str


class MappingNode(Node):
    """Maps tracked frames (shared pipeline in slam_node, or standalone with poses from a topic)."""

    def __init__(
        self, pipeline: SlamPipeline | None = None, camera_frame: Callable[[], str] | None = None, **kwargs: object
    ) -> None:
        """``pipeline``: share a composed tracking node's; ``camera_frame``: its camera frame id."""
        super().__init__("mapping_node", **kwargs)
        self.params = declare(self, COMMON + MAPPING + EDIT)
        use_threads(self.params)
        self.map_frame = self.params["map_frame"]
        self._owns_pipeline = pipeline is None
        self._camera_frame = camera_frame
        self.mapped_rate = RateMeter()
        self.last_mapped_stamp = -1
        self._view: _View | None = None
        self._render_lock = threading.Lock()
        self.camera: CameraInputs | None = None  # standalone: its own camera inputs
        self.reset_listeners: list[Callable[[], None]] = []  # e.g. the composed tracking node's state
        self._frames: OrderedDict[int, Frame] = OrderedDict()  # standalone: frames waiting for their pose
        self._poses: OrderedDict[int, np.ndarray] = OrderedDict()  # and poses waiting for their frame
        self._pair_lock, self._paired_stamp = threading.Lock(), -1  # the stamp of the last frame handed over
        if pipeline is None:
            slam = Slam(slam_config(self.params))
            slam.prepare(self.get_logger().info)  # compile the CPU kernels now, not inside the first frame
            pipeline = SlamPipeline(
                slam,
                self.params["lockstep"],
                track=False,
                map=True,
                log=self.get_logger().error,
                late_labels=self.params["use_semantics"],
            )
            self._subscribe_inputs(pipeline)
        self.pipeline = pipeline
        # render.compile, standalone: traced on the first frame, not in the first windows (composed: by tracking)
        self._compile_pending = self._owns_pipeline and pipeline.slam.config.render.compile
        self.saver = self._saver()
        pipeline.map_listeners.append(self._on_mapped)
        pipeline.label_listeners.append(lambda *_: self._classes_changed())
        out = output_qos(2)
        self.color_pub = self.create_publisher(Image, "~/render/color", out)
        self.semantic_pub = self.create_publisher(Image, "~/render/semantic", out)
        self.labels_pub = self.create_publisher(Image, "~/render/labels", out)
        self.depth_pub = self.create_publisher(Image, "~/render/depth", out)
        self.render_info_pub = self.create_publisher(CameraInfo, "~/render/camera_info", out)
        self.points_pub = self.create_publisher(PointCloud2, "~/points", latched_qos())
        self.gaussians_pub = self.create_publisher(PointCloud2, "~/gaussians", latched_qos())
        self.renders = Throttled(self, self.params["render_rate_hz"], self.publish_renders)
        self.points_out = Throttled(self, self.params["points_rate_hz"], self.publish_points)
        self.gaussians_out = Throttled(self, self.params["gaussians_rate_hz"], self.publish_gaussians)
        self.params.on_change["render_rate_hz"] = self.renders.set_rate
        self.params.on_change["points_rate_hz"] = self.points_out.set_rate
        self.params.on_change["gaussians_rate_hz"] = self.gaussians_out.set_rate
        self.create_service(Trigger, "~/save_map", self._save_map)
        self.create_service(Trigger, "~/load_map", self._load_map)
        self.create_service(Trigger, "~/reset", self._reset)
        self.create_service(SetBool, "~/pause", self._pause)
        self.create_service(Trigger, "~/apply_edit", self._apply_edit)
        self.create_service(Trigger, "~/undo_edit", self._undo_edit)
        self.diagnostics = Diagnostics(self, self._status)
        if self.params["load_map_on_start"]:
            self._load_on_start()

    def _saver(self) -> MapSaver:
        """The map file's saver: on request, every ``autosave_period_s``, at shutdown; follows ``map_path``."""
        log = self.get_logger()
        path = map_file_path(self.params["map_path"])
        p = self.pipeline
        saver = MapSaver(path, p.map_file, self.params["autosave_period_s"], log.info, log.error, p.background_turn)
        self.params.on_change["map_path"] = lambda value: saver.move_to(map_file_path(value))
        return saver

    # ------------------------------------------------------------------ standalone inputs
    def _subscribe_inputs(self, pipeline: SlamPipeline) -> None:
        self.activity = Activity(pipeline.idle)
        self.camera = CameraInputs(
            self,
            self.params,
            self._on_frame,
            self.activity,
            {"pose": "tracking_node/pose"},
            {"pose": "is tracking_node running?"},
            on_labels=lambda stamp_ns, labels: pipeline.submit_labels(stamp_ns, labels, time.monotonic()),
            forwarded_by="tracking_node" if self.params["frame_source"] == "tracking_node" else None,
        )
        self.create_subscription(PoseStamped, "tracking_node/pose", self._on_pose, output_qos(50))

    def _on_frame(self, frame: Frame) -> None:
        if self._compile_pending:
            self._compile_pending = False
            self.pipeline.slam.prepare(self.get_logger().info, frame)
        with self._pair_lock:
            self._frames[frame.stamp_ns] = frame
            self._pair()

    def _on_pose(self, msg: PoseStamped) -> None:
        self.camera.watch.tick("pose")
        try:
            c2w = pose_to_c2w(msg)
        except AdapterError as err:
            self.camera.assembler.reject("bad pose", str(err))
            return
        with self._pair_lock:
            self._poses[stamp_to_ns(msg.header.stamp)] = c2w
            self._pair()

    def _pair(self) -> None:
        """Map each frame whose pose came; let go of those older than the newest pair, which cannot pair now."""
        paired = [s for s in self._frames if s in self._poses]
        for stamp in paired:
            frame, c2w = self._frames.pop(stamp), self._poses.pop(stamp)
            if stamp <= self._paired_stamp:  # sent again by a lockstep tracker waiting on a busy map: mapped
                continue
            self._paired_stamp = stamp
            self.activity.begin()
            self.pipeline.submit_job(MapJob(frame, c2w=c2w))
        if paired:  # both streams come in stamp order
            for stale in [s for s in self._frames if s < paired[-1]]:
                del self._frames[stale]
                self.pipeline.count_dropped()
            for stale in [s for s in self._poses if s < paired[-1]]:
                del self._poses[stale]  # its frame was not accepted (not forwarded), or was lost on the way
        for queue in (self._frames, self._poses):
            while len(queue) > _PENDING:
                queue.popitem(last=False)
                self.pipeline.count_dropped()

    # ------------------------------------------------------------------ outputs
    def camera_frame(self) -> str:
        """Frame id of the camera: the parameter, else the input's header (composed: the tracker's)."""
        if self.params["camera_frame"]:
            return self.params["camera_frame"]
        if self._camera_frame is not None:
            return self._camera_frame()
        return (self.camera.assembler.frame_id if self.camera else "") or CAMERA_FRAME

    def _on_mapped(self, frame: Frame, tracked: TrackOutcome, result: MapOutcome) -> None:
        if not self.context.ok():  # shutting down: the publishers are gone
            return
        self.mapped_rate.tick()
        if self.camera is not None:
            self.activity.end()
        self.last_mapped_stamp = tracked.stamp_ns
        self._view = _View(tracked.stamp_ns, np.array(tracked.c2w, dtype=np.float64), self.camera_frame())
        self._map_changed()
        if self.params["lockstep"] or (self.camera is not None and self.gaussians_out.count == 0):
            self.gaussians_out.now()  # a tracker in another process waits for this map (live: for its first)

    def _classes_changed(self) -> None:
        """Late labels changed classes: the clouds publish them; the renders wait for the next mapped frame's view."""
        self.saver.mark_changed()
        self.points_out.mark()
        self.gaussians_out.mark()

    def _map_changed(self) -> None:
        """New content: each output publishes it once, at most at its rate, and the next save writes it."""
        self.saver.mark_changed()
        self.renders.mark()
        self.points_out.mark()
        self.gaussians_out.mark()

    def publish_renders(self) -> bool:
        """Render the map from the newest mapped frame's pose; publish colour, semantics, labels, depth.

        False (nothing rendered) before a frame is mapped and while no one subscribes any of them.
        """
        renders = (self.color_pub, self.semantic_pub, self.labels_pub, self.depth_pub, self.render_info_pub)
        if not any(pub.get_subscription_count() for pub in renders):
            return False
        snap, view = self.pipeline.snapshot(), self._view
        if view is None or len(snap.gaussians) == 0 or snap.intrinsics is None:
            return False
        with self._render_lock, torch.no_grad():
            out = self.pipeline.render_view(snap, view.c2w)
            color = (out.color.clamp(0, 1) * 255).round().to(torch.uint8).cpu().numpy()
            if out.semantic.shape[-1]:
                labels = snap.decode_image(out.semantic).cpu().numpy()
            else:
                labels = np.zeros(color.shape[:2], int)
            labels = np.where(out.silhouette.cpu().numpy() > 0.5, labels, 0)
            depth = out.depth.cpu().numpy().astype(np.float32)
        stamp, frame_id = view.stamp_ns, view.frame_id
        self.render_info_pub.publish(camera_info_msg(snap.intrinsics, stamp, frame_id))
        self.color_pub.publish(image_msg(color, "rgb8", stamp, frame_id))
        self.semantic_pub.publish(image_msg(snap.codec.table.colorize(labels), "rgb8", stamp, frame_id))
        self.labels_pub.publish(image_msg(labels.astype(np.uint16), "16UC1", stamp, frame_id))
        self.depth_pub.publish(image_msg(depth, "32FC1", stamp, frame_id))
        return True

    def points(self) -> np.ndarray:
        """The map as coloured, labelled points (every Gaussian centre, subsampled to ``points_max``)."""
        g = self.pipeline.snapshot().gaussians.detach().to("cpu")
        step = max(1, int(np.ceil(len(g) / self.params["points_max"])))
        pts = np.zeros(len(range(0, len(g), step)), dtype=POINT_DTYPE)
        means = g.means[::step].float().numpy()
        pts["x"], pts["y"], pts["z"] = means.T
        pts["rgb"] = pack_rgb((g.colors[::step].clamp(0, 1) * 255).round().to(torch.uint8).numpy())
        pts["label"] = g.labels[::step].numpy().astype(np.uint32)
        return pts

    def publish_points(self) -> bool:
        """Publish ``~/points`` (empty after a reset, so latched viewers clear); False while no one subscribes."""
        if self.points_pub.get_subscription_count() == 0:
            return False
        self.points_pub.publish(pointcloud_msg(self.points(), self._stamp(), self.map_frame))
        return True

    def publish_gaussians(self) -> bool:
        """Publish the whole map on ``~/gaussians`` (stamp = the last mapped frame); False while no one subscribes."""
        if self.gaussians_pub.get_subscription_count() == 0:
            return False
        cloud = gaussians_to_cloud(self.pipeline.snapshot().gaussians)
        self.gaussians_pub.publish(pointcloud_msg(cloud, self._stamp(), self.map_frame))
        return True

    def _stamp(self) -> int:
        """The newest mapped frame's stamp (the node's clock before the first)."""
        return self.last_mapped_stamp if self.last_mapped_stamp >= 0 else self.get_clock().now().nanoseconds

    # ------------------------------------------------------------------ services
    def _save_map(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        outcome = self.saver.save()
        response.success, response.message = outcome.saved, outcome.message
        return response

    def _load_map(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        try:
            saved = self.load(self.saver.path)
            relocalizing = self.pipeline.stats.tracking_state == "lost"
            response.success, response.message = True, _loaded(saved, self.saver.path, relocalizing)
        except (OSError, SgsSlamError, TimeoutError) as err:
            response.success, response.message = False, f"cannot load {self.saver.path}: {err}"
        return response

    def _load_on_start(self) -> None:
        """``load_map_on_start``: go on in the saved map if there is one; an unreadable one stops the node."""
        path = self.saver.path
        if not path.exists():
            self.get_logger().info(f"no map at {path} yet: starting a new one")
            return
        try:
            saved = self.load(path)
        except (SgsSlamError, TimeoutError) as err:
            self.close()
            raise SgsSlamError(f"{err} (move it away, or start with load_map_on_start:=false)") from err
        self.get_logger().info(_loaded(saved, path, self.pipeline.stats.tracking_state == "lost"))

    def load(self, path: FilePath) -> MapFile:
        """Load the map at ``path`` and go on in it: the next frames are relocalized in it before mapping."""
        saved = load_map(path, self.pipeline.slam.device)
        with self.saver.held():  # no autosave of the map being replaced lands after the load
            self.pipeline.load_map(saved, relocalize=True)
        if self.camera is not None:
            self.camera.assembler.reset()
        if saved.trajectory:  # render the loaded map from its last pose until new frames are mapped
            _, stamp, c2w = saved.trajectory[-1]
            self.last_mapped_stamp = stamp
            self._view = _View(stamp, np.asarray(c2w, dtype=np.float64), self.camera_frame())
        self._map_changed()
        self.saver.mark_saved()  # what the outputs publish is the file's map
        self.gaussians_out.now()
        return saved

    def _apply_edit(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        done = []
        try:
            edits = requested_edits(self.params)
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
        if response.success:  # the edited map right away, the rest at their rates
            self._map_changed()
            self.gaussians_out.now()

    def _reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        response.success = self.pipeline.reset()
        self.after_reset()
        for listener in self.reset_listeners:
            listener()
        response.message = "map cleared" if response.success else "timed out waiting for the workers"
        self.get_logger().info(f"~/reset: {response.message}")
        return response

    def after_reset(self) -> None:
        """Forget this node's per-run state and publish the empty map (latched viewers clear).

        The map file is left as it is: an empty map is not saved over it.
        """
        self.saver.mark_saved()
        if self.camera is not None:
            self.camera.reset()
        with self._pair_lock:
            self._frames.clear()
            self._poses.clear()
            self._paired_stamp = -1
        self.last_mapped_stamp = -1
        self._view = None
        self.points_out.now()
        self.gaussians_out.now()

    def _pause(self, request: SetBool.Request, response: SetBool.Response) -> SetBool.Response:
        self.pipeline.pause(bool(request.data))
        response.success, response.message = True, "paused" if request.data else "running"
        return response

    def _status(self) -> tuple[int, str, dict[str, str]]:
        st = self.pipeline.stats
        level, message = OK, "paused" if self.pipeline.paused else "mapping"
        if st.errors:
            level, message = WARN, f"errors: {st.last_error}"
        if self.saver.stats.last_error:
            level, message = WARN, f"map not saved: {self.saver.stats.last_error}"
        values = {
            "processing_rate_hz": f"{self.mapped_rate.rate():.2f}",
            "frames_mapped": str(st.mapped),
            "jobs_dropped": str(st.dropped_jobs),
            "mapping_steps_per_frame": f"{st.map_steps_per_frame:.1f}",
            **footprint(self.pipeline.slam).as_strings(),  # Gaussians, keyframes held, and their bytes
            "tracking_failures": str(st.tracking_failures),
            **_label_counts(st),
            "locked_classes": " ".join(str(i) for i in sorted(self.pipeline.slam.locked_labels)) or "none",
            "undoable_edits": str(self.pipeline.slam.edits.depth),
            **_save_values(self.saver.path, self.saver.stats, st.snapshot_hold_s),
            "renders_published": str(self.renders.count),
            "render_size": "n/a"
            if self.pipeline.slam.intrinsics is None
            else f"{self.pipeline.slam.intrinsics.width}x{self.pipeline.slam.intrinsics.height}",
        }
        if self.camera is not None:  # standalone: its own inputs
            silent, warning = self.camera.silence(self.params["stale_input_s"], "nothing mapped")
            values.update(self.camera.counts(st.dropped_frames))
            values.update(self.camera.sizes())
            values.update(self.camera.transport())
            values["silent_inputs"] = self.camera.silent_names(silent)
            if warning is not None:
                level, message = warning
        return level, message, values

    def finish(self) -> None:
        """Before the process exits (SIGINT, SIGTERM): map the frames in hand, then save the map.

        Mapping jobs end at their next step (:meth:`SlamPipeline.finish`): the frames are in the
        map, the exit does not wait for their refinement.

        Saved (``save_on_shutdown``) only if it changed since it was last saved or loaded. A
        second signal exits at once (:mod:`sgs_slam_ros.runtime`), leaving the last complete file.
        """
        self.saver.close()
        if not self.params["save_on_shutdown"]:
            return
        log = self.get_logger()
        if not self.pipeline.finish(_FINISH_S):
            log.warn(f"the frames in hand did not finish within {_FINISH_S:.0f} s: saving the map as it is")
        if not self.saver.changed:
            log.info(f"map unchanged since it was last saved or loaded: {self.saver.path} left as it is")
            return
        outcome = self.saver.save()
        (log.info if outcome.saved else log.error)(f"at shutdown: {outcome.message}")

    def close(self) -> None:
        """Stop autosaving and the workers this node owns; standalone, log the run's frame counts."""
        self.saver.close()
        if self._owns_pipeline:
            self.pipeline.shutdown()
        if self.camera is not None:
            st = self.pipeline.stats
            counts = self.camera.counts(st.dropped_frames)
            counts["frames_mapped"] = str(st.mapped)
            counts["jobs_dropped"] = str(st.dropped_jobs)
            counts["mapping_steps_per_frame"] = f"{st.map_steps_per_frame:.1f}"
            self.get_logger().info("final counts: " + ", ".join(f"{k} {v}" for k, v in counts.items()))


def _loaded(saved: MapFile, path: FilePath, relocalizing: bool) -> str:
    then = (
        "the camera is relocalized in it before mapping goes on"
        if relocalizing
        else "tracking goes on from its last pose (no relocalization: features off or no keyframe images)"
    )
    return (
        f"loaded {len(saved.gaussians)} Gaussians, {len(saved.keyframes)} keyframes and {len(saved.trajectory)} "
        f"poses from {path}; {then}"
    )


def _save_values(path: FilePath, s: SaveStats, hold_s: float) -> dict[str, str]:
    """The map file's saves for /diagnostics: counts, and the last one's age, size and time."""
    age = "n/a" if s.last_saved_at is None else f"{time.time() - s.last_saved_at:.0f}"
    return {
        "map_path": str(path),
        "map_saves": str(s.saves),
        "map_save_failures": str(s.failures),
        "last_save_age_s": age,
        "last_save_frames": str(s.last_frames),
        "last_save_mb": f"{s.last_bytes / 2**20:.1f}",
        "last_save_ms": f"{1e3 * (s.last_snapshot_s + s.last_write_s):.0f}",
        "last_save_hold_ms": f"{1e3 * hold_s:.1f}",  # how long the snapshot held tracking and mapping
        "last_save_error": s.last_error or "none",
    }


def _label_counts(st: PipelineStats) -> dict[str, str]:
    """Late label images for /diagnostics: in, fused, unmatched, pending, and the latency to their fusion."""
    c = st.labels
    latency = sorted(st.label_latency_s)
    return {
        "labels_in": str(c.labels_in),
        "labels_fused": str(c.labels_fused),
        "labels_unmatched": str(c.labels_unmatched),
        "label_latency_ms": f"{1e3 * latency[len(latency) // 2]:.0f}" if latency else "n/a",
    }


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run sgs_slam_ros mapping_node`` (standalone, poses from tracking_node)."""
    return run_nodes(lambda: [MappingNode()], args)


if __name__ == "__main__":
    raise SystemExit(main())
