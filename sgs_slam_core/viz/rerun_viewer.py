"""Rerun backend of the live viewer (rerun-sdk).

Entities (timelines ``frame`` and ``stamp``):

* ``world`` - the map frame (camera optical convention, right-down-forward).
* ``world/camera`` - estimated pose and pinhole; ``world/camera/input/{rgb,depth,labels}`` the input.
* ``world/trajectory`` and ``world/ground_truth`` - camera paths (ground truth anchored at the
  first frame that has it, as the SLAM map is).
* ``world/map`` - Gaussian centres with colours and class ids (every ``points_every`` frames).
* ``render/{color,depth,semantic}`` - the map rendered from the estimated pose.
* ``stats/{gaussians,track_ms,map_ms}`` - scalars; ``log`` - tracking failures.
"""

from __future__ import annotations

import os
import shutil
import sys
import uuid
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from sgs_slam_core.labels import LabelTable
from sgs_slam_core.viz.snapshot import MapPoints, Snapshot
from sgs_slam_core.viz.viewer import StreamingViewer, ViewerOptions, check_port_free

__all__ = ["RerunViewer"]

_ESTIMATE_RGB = (30, 110, 230)
_GT_RGB = (90, 90, 90)


def _has_display() -> bool:
    return sys.platform in ("darwin", "win32") or bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def _viewer_executable() -> str | None:
    """``rerun`` on PATH or beside this interpreter (a venv that is not activated)."""
    found = shutil.which("rerun")
    if found:
        return found
    local = Path(sys.executable).parent / "rerun"
    return str(local) if local.is_file() else None


def _spawnable() -> bool:
    return _has_display() and _viewer_executable() is not None


def _blueprint() -> rrb.Blueprint:
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="world", name="map"),
            rrb.Vertical(
                rrb.Spatial2DView(origin="world/camera/input", name="input"),
                rrb.Spatial2DView(origin="render", contents=["render/color"], name="rendered colour"),
                rrb.Spatial2DView(origin="render", contents=["render/semantic"], name="rendered classes"),
                rrb.TimeSeriesView(origin="stats", name="stats"),
            ),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


class RerunViewer(StreamingViewer):
    """Streams snapshots to a Rerun viewer and/or an ``.rrd`` file."""

    def __init__(self, options: ViewerOptions) -> None:
        super().__init__(options)
        self.rec = rr.RecordingStream("sgs-slam", recording_id=uuid.uuid4())
        self.port, self.web_port = options.port or 9876, options.web_port or 9090
        self.url = f"rerun+http://{options.host}:{self.port}/proxy"
        if options.live and _spawnable():
            self.where.append(f"rerun: spawning the Rerun viewer (port {self.port}; a running one is reused)")
        elif options.live:  # serving: fail now rather than at the first frame
            check_port_free(options.host, self.port)
            check_port_free(options.host, self.web_port)
            self.where.append(
                f"rerun: no display here; open http://{options.host}:{self.web_port} in a browser "
                f"or run `rerun --connect {self.url}`"
            )
        if options.save is not None:
            self.where.append(f"rerun: recording to {options.save} (open with `rerun {options.save}`)")

    def _open_sinks(self) -> None:
        """Sinks open with the first frame, so that a recording inside the run folder survives its set-up."""
        sinks: list[rr.FileSink | rr.GrpcSink | rr.GrpcServerSink] = []
        if self.options.live:
            sinks.append(self._live_sink())
        if self.options.save is not None:
            self.options.save.parent.mkdir(parents=True, exist_ok=True)
            sinks.append(rr.FileSink(str(self.options.save)))
        self.rec.set_sinks(*sinks, default_blueprint=_blueprint())

    def _live_sink(self) -> rr.GrpcSink | rr.GrpcServerSink:
        exe = _viewer_executable()
        if exe is not None and _spawnable():
            os.environ["PATH"] = f"{Path(exe).parent}{os.pathsep}{os.environ.get('PATH', '')}"  # spawn looks on PATH
            self.rec.spawn(port=self.port, connect=False)
            return rr.GrpcSink(f"rerun+http://127.0.0.1:{self.port}/proxy")
        sink = rr.GrpcServerSink(bind_ip=self.options.host, port=self.port)
        rr.serve_web_viewer(web_port=self.web_port, open_browser=False, connect_to=self.url)
        return sink

    # ------------------------------------------------------------------ backend interface
    def start(self, table: LabelTable) -> None:
        """Open the sinks; send the map-frame convention and the class table (names, colours)."""
        self._open_sinks()
        self.rec.log("world", rr.ViewCoordinates.RDF, static=True)
        infos = [rr.AnnotationInfo(id=c.id, label=c.name, color=c.color) for c in table]
        self.rec.log("/", rr.AnnotationContext(infos), static=True)

    def _set_time(self, index: int, stamp_ns: int) -> None:
        self.rec.set_time("frame", sequence=index)
        self.rec.set_time("stamp", timestamp=np.datetime64(stamp_ns, "ns"))

    def send(self, snap: Snapshot) -> None:
        """Pose, input, renders, paths, scalars and (when due) the map's points."""
        rec, k = self.rec, snap.intrinsics
        self._set_time(snap.index, snap.stamp_ns)
        rec.log("world/camera", rr.Transform3D(translation=snap.c2w[:3, 3], mat3x3=snap.c2w[:3, :3]))
        rec.log(
            "world/camera/input",
            rr.Pinhole(
                image_from_camera=k.matrix(),
                resolution=[k.width, k.height],
                camera_xyz=rr.ViewCoordinates.RDF,
                image_plane_distance=0.3,
            ),
        )
        rec.log("world/camera/input/rgb", rr.Image(snap.rgb))
        rec.log("world/camera/input/depth", rr.DepthImage(snap.depth, meter=1.0))
        if snap.labels is not None:
            rec.log("world/camera/input/labels", rr.SegmentationImage(snap.labels.astype(np.uint16)))
        if snap.render_rgb is not None:
            rec.log("render/color", rr.Image(snap.render_rgb))
            rec.log("render/depth", rr.DepthImage(snap.render_depth, meter=1.0))
        if snap.render_labels is not None:
            rec.log("render/semantic", rr.SegmentationImage(snap.render_labels.astype(np.uint16)))
        rec.log("world/trajectory", rr.LineStrips3D([snap.path], colors=[_ESTIMATE_RGB]))
        if snap.gt_path is not None:
            rec.log("world/ground_truth", rr.LineStrips3D([snap.gt_path], colors=[_GT_RGB]))
        rec.log("stats/gaussians", rr.Scalars(float(snap.num_gaussians)))
        rec.log("stats/track_ms", rr.Scalars(snap.track_ms))
        rec.log("stats/map_ms", rr.Scalars(snap.map_ms))
        if snap.tracking_failed:
            rec.log("log", rr.TextLog(f"frame {snap.index}: tracking failed", level=rr.TextLogLevel.WARN))
        if snap.points is not None:
            self._log_points(snap.points)

    def _log_points(self, points: MapPoints) -> None:
        self.rec.log(
            "world/map",
            rr.Points3D(points.positions, colors=points.colors, class_ids=points.labels.astype(np.uint16), radii=0.005),
        )

    def send_points(self, index: int, stamp_ns: int, points: MapPoints) -> None:
        """The final map at the last frame's time."""
        self._set_time(index, stamp_ns)
        self._log_points(points)

    def finish(self) -> None:
        """Flush every sink (the ``.rrd`` file is complete afterwards)."""
        self.rec.flush()
        self.rec.disconnect()
