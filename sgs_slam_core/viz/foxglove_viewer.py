"""Foxglove backend of the live viewer (foxglove-sdk): a WebSocket server and/or an MCAP file.

Channels (log time = frame stamp; frames ``map`` and ``camera``):

* ``/tf`` (foxglove.FrameTransforms) - ``map -> camera``, the estimated pose.
* ``/camera/image``, ``/camera/depth`` (32FC1 m), ``/camera/labels`` (rgb8 class colours),
  ``/camera/calibration`` - the input.
* ``/render/color``, ``/render/depth``, ``/render/semantic`` - the map seen from the estimated pose.
* ``/slam/paths`` (foxglove.SceneUpdate) - estimated and ground-truth camera paths as lines.
* ``/map/points`` (foxglove.PointCloud: x, y, z, red, green, blue, alpha, label) - Gaussian centres.
* ``/slam/status`` (JSON) - frame, Gaussians, tracking and mapping times, tracking failure.
"""

from __future__ import annotations

import numpy as np
import torch
from foxglove import Channel, Context, open_mcap, start_server
from foxglove import channels as fch
from foxglove import messages as fm

from sgs_slam_core.errors import BackendUnavailableError
from sgs_slam_core.frame_ids import CAMERA_FRAME, MAP_FRAME
from sgs_slam_core.geometry.se3 import rotmat_to_quat
from sgs_slam_core.labels import LabelTable
from sgs_slam_core.viz.snapshot import MapPoints, Snapshot
from sgs_slam_core.viz.viewer import StreamingViewer, ViewerOptions

__all__ = ["STATUS_SCHEMA", "FoxgloveViewer"]

STATUS_SCHEMA = {
    "type": "object",
    "properties": {
        "frame": {"type": "integer"},
        "gaussians": {"type": "integer"},
        "track_ms": {"type": "number"},
        "map_ms": {"type": "number"},
        "tracking_failed": {"type": "boolean"},
    },
}
_F = fm.PackedElementFieldNumericType
_POINT_FIELDS = (
    ("x", 0, _F.Float32),
    ("y", 4, _F.Float32),
    ("z", 8, _F.Float32),
    ("red", 12, _F.Uint8),
    ("green", 13, _F.Uint8),
    ("blue", 14, _F.Uint8),
    ("alpha", 15, _F.Uint8),
    ("label", 16, _F.Uint16),
)
_POINT_DTYPE = np.dtype([("xyz", "<f4", 3), ("rgba", "u1", 4), ("label", "<u2")])  # 18 bytes per point


def _stamp(ns: int) -> fm.Timestamp:
    return fm.Timestamp(sec=ns // 1_000_000_000, nsec=ns % 1_000_000_000)


def _image(data: np.ndarray, encoding: str, stamp_ns: int) -> fm.RawImage:
    data = np.ascontiguousarray(data)
    h, w = data.shape[:2]
    return fm.RawImage(
        timestamp=_stamp(stamp_ns),
        frame_id=CAMERA_FRAME,
        width=w,
        height=h,
        encoding=encoding,
        step=data.strides[0],
        data=data.tobytes(),
    )


def _line(points: np.ndarray, rgb: tuple[float, float, float]) -> fm.LinePrimitive:
    return fm.LinePrimitive(
        type=fm.LinePrimitiveLineType.LineStrip,
        thickness=2.0,
        scale_invariant=True,
        points=[fm.Point3(x=float(p[0]), y=float(p[1]), z=float(p[2])) for p in points],
        color=fm.Color(r=rgb[0], g=rgb[1], b=rgb[2], a=1.0),
    )


class FoxgloveViewer(StreamingViewer):
    """Streams snapshots to Foxglove (WebSocket) and/or an MCAP file."""

    def __init__(self, options: ViewerOptions) -> None:
        super().__init__(options)
        self.ctx = Context()
        self.server = self.writer = None
        if options.live:
            port = options.port or 8765
            try:
                self.server = start_server(name="sgs-slam", host=options.host, port=port, context=self.ctx)
            except (RuntimeError, OSError, ValueError) as err:
                raise BackendUnavailableError(f"foxglove server could not start on port {port}: {err}") from err
            self.where.append(f"foxglove: open Foxglove and connect to ws://{options.host}:{port}")
        if options.save is not None:
            self.where.append(f"foxglove: recording to {options.save} (open it in Foxglove)")
        c = self.ctx
        self.tf = fch.FrameTransformsChannel("/tf", context=c)
        self.images = {
            name: fch.RawImageChannel(name, context=c)
            for name in (
                "/camera/image",
                "/camera/depth",
                "/camera/labels",
                "/render/color",
                "/render/depth",
                "/render/semantic",
            )
        }
        self.calibration = fch.CameraCalibrationChannel("/camera/calibration", context=c)
        self.paths = fch.SceneUpdateChannel("/slam/paths", context=c)
        self.points = fch.PointCloudChannel("/map/points", context=c)
        self.status = Channel("/slam/status", schema=STATUS_SCHEMA, message_encoding="json", context=c)
        self.table = LabelTable()

    # ------------------------------------------------------------------ backend interface
    def start(self, table: LabelTable) -> None:
        """Open the MCAP file (with the first frame, so a file inside the run folder survives its set-up)."""
        self.table = table
        if self.options.save is not None:
            self.options.save.parent.mkdir(parents=True, exist_ok=True)
            self.writer = open_mcap(str(self.options.save), allow_overwrite=True, context=self.ctx)

    def send(self, snap: Snapshot) -> None:
        """Pose, input, renders, paths, status and (when due) the map's points."""
        t = snap.stamp_ns
        self._send_camera(snap, t)
        self._send_images(snap, t)
        entities = [
            fm.SceneEntity(
                timestamp=_stamp(t), frame_id=MAP_FRAME, id="trajectory", lines=[_line(snap.path, (0.12, 0.43, 0.9))]
            )
        ]
        if snap.gt_path is not None:
            entities.append(
                fm.SceneEntity(
                    timestamp=_stamp(t),
                    frame_id=MAP_FRAME,
                    id="ground_truth",
                    lines=[_line(snap.gt_path, (0.35, 0.35, 0.35))],
                )
            )
        self.paths.log(fm.SceneUpdate(entities=entities), log_time=t)
        self.status.log(
            {
                "frame": snap.index,
                "gaussians": snap.num_gaussians,
                "track_ms": round(snap.track_ms, 2),
                "map_ms": round(snap.map_ms, 2),
                "tracking_failed": snap.tracking_failed,
            },
            log_time=t,
        )
        if snap.points is not None:
            self.send_points(snap.index, t, snap.points)

    def _send_camera(self, snap: Snapshot, t: int) -> None:
        """The camera's pose in the map and its calibration."""
        q = rotmat_to_quat(torch.from_numpy(snap.c2w[:3, :3].copy())).numpy()  # wxyz
        pos = snap.c2w[:3, 3]
        tf = fm.FrameTransform(
            timestamp=_stamp(t),
            parent_frame_id=MAP_FRAME,
            child_frame_id=CAMERA_FRAME,
            translation=fm.Vector3(x=float(pos[0]), y=float(pos[1]), z=float(pos[2])),
            rotation=fm.Quaternion(x=float(q[1]), y=float(q[2]), z=float(q[3]), w=float(q[0])),
        )
        self.tf.log(fm.FrameTransforms(transforms=[tf]), log_time=t)
        k = snap.intrinsics
        self.calibration.log(
            fm.CameraCalibration(
                timestamp=_stamp(t),
                frame_id=CAMERA_FRAME,
                width=k.width,
                height=k.height,
                distortion_model="plumb_bob",
                D=[0.0] * 5,
                K=[k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0],
                R=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
                P=[k.fx, 0.0, k.cx, 0.0, 0.0, k.fy, k.cy, 0.0, 0.0, 0.0, 1.0, 0.0],
            ),
            log_time=t,
        )

    def _send_images(self, snap: Snapshot, t: int) -> None:
        """The input images and, when rendered, the map's views."""
        img = self.images
        img["/camera/image"].log(_image(snap.rgb, "rgb8", t), log_time=t)
        img["/camera/depth"].log(_image(snap.depth.astype(np.float32), "32FC1", t), log_time=t)
        if snap.labels is not None:
            img["/camera/labels"].log(_image(self.table.colorize(snap.labels), "rgb8", t), log_time=t)
        if snap.render_rgb is not None and snap.render_depth is not None:
            img["/render/color"].log(_image(snap.render_rgb, "rgb8", t), log_time=t)
            img["/render/depth"].log(_image(snap.render_depth.astype(np.float32), "32FC1", t), log_time=t)
        if snap.render_labels is not None:
            img["/render/semantic"].log(_image(self.table.colorize(snap.render_labels), "rgb8", t), log_time=t)

    def send_points(self, index: int, stamp_ns: int, points: MapPoints) -> None:
        """The Gaussian centres as a packed point cloud in ``map``."""
        packed = np.zeros(len(points.positions), _POINT_DTYPE)
        packed["xyz"] = points.positions
        packed["rgba"][:, :3] = points.colors
        packed["rgba"][:, 3] = 255
        packed["label"] = np.clip(points.labels, 0, 65535)
        fields = [fm.PackedElementField(name=n, offset=o, type=ty) for n, o, ty in _POINT_FIELDS]
        self.points.log(
            fm.PointCloud(
                timestamp=_stamp(stamp_ns),
                frame_id=MAP_FRAME,
                point_stride=_POINT_DTYPE.itemsize,
                fields=fields,
                data=packed.tobytes(),
            ),
            log_time=stamp_ns,
        )

    def finish(self) -> None:
        """Close the MCAP file (writes its summary) and stop the server."""
        if self.writer is not None:
            self.writer.close()
            self.writer = None
        if self.server is not None:
            self.server.stop()
            self.server = None
