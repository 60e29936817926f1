"""The camera topics of a node: subscriptions, frame assembly, silence watch and their live parameters.

Shared by ``tracking_node`` and a standalone ``mapping_node``: both subscribe ``{rgb,depth}/image``
and ``rgb/camera_info`` with the input QoS, synchronise them into frames (:class:`FrameAssembler`),
take ``semantic/image`` apart from them (a node that maps, with ``use_semantics``), and
report inputs that stay silent while the node waits (:class:`InputWatch`, :class:`Activity`) and
frames that never arrived (gaps in each stream's stamps, :class:`StreamGaps`).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image

from msg_adapters import stamp_to_ns
from sgs_slam_core.frame import Frame
from sgs_slam_core.slam.system import resolve_device
from sgs_slam_ros.activity import Activity
from sgs_slam_ros.diagnostics import OK, WARN, RateMeter
from sgs_slam_ros.forward import forwarded_topic
from sgs_slam_ros.frames import AUTO_DOWNSCALE, FrameAssembler
from sgs_slam_ros.inputs import InputWatch
from sgs_slam_ros.params import NodeParams
from sgs_slam_ros.qos import input_qos
from sgs_slam_ros.stream_gaps import GapReport, StreamGaps
from sgs_slam_ros.transport import PROFILE_ENV, socket_buffer_advice

__all__ = ["CameraInputs"]

_LOSS_LOG_S = 10.0  # after the first, losses are logged at most this often (with running totals)


class CameraInputs:
    """Subscribes a node's camera topics and hands each synchronised frame to ``on_frame``.

    ``extra_topics``: further inputs the node subscribes itself (name -> topic relative to the node),
    watched for silence too (the node calls ``watch.tick(name)``); ``hints``: a sentence per input
    added to its "silent" log line; ``activity``: the node's work (silence counts only while idle).
    ``on_labels(stamp_ns, labels)``: label images at the processing size (None: ``semantic/image`` is
    not subscribed; with ``use_semantics`` off neither). ``forwarded_by``: subscribe that tracking
    node's forwarded frames (``<node>/frames/...``, :mod:`sgs_slam_ros.forward`) instead of the
    camera's: they come at the processing size, and the frames it did not accept are gaps that are
    not losses, so stamp gaps are not counted.
    """

    def __init__(
        self,
        node: Node,
        params: NodeParams,
        on_frame: Callable[[Frame], None],
        activity: Activity,
        extra_topics: dict[str, str] | None = None,
        hints: dict[str, str] | None = None,
        on_labels: Callable[[int, np.ndarray], None] | None = None,
        forwarded_by: str | None = None,
    ) -> None:
        self.logger = node.get_logger()
        log = self.logger.warn
        self.log, self.activity = log, activity
        labelled = params["use_semantics"] and on_labels is not None
        self.assembler = FrameAssembler(
            params["sync_queue_size"],
            round(params["sync_slop_s"] * 1e9),
            params["depth_scale"],
            on_frame,
            log,
            params["downscale"] if forwarded_by is None else 1.0,
            on_labels if labelled else None,
            cpu=resolve_device(params["device"]).type == "cpu",
        )
        params.on_change["sync_slop_s"] = self.assembler.set_slop
        params.on_change["depth_scale"] = lambda v: setattr(self.assembler, "depth_scale", v)
        self.colour_rate = RateMeter()
        qos = input_qos(params["input_qos"], params["input_queue_size"])
        names = ["rgb", "depth", *(["semantic"] if labelled else [])]
        topic = (lambda t: t) if forwarded_by is None else (lambda t: forwarded_topic(forwarded_by, t))
        for i, name in enumerate(names[:2]):
            node.create_subscription(Image, topic(f"{name}/image"), lambda m, i=i, n=name: self._image(i, n, m), qos)
        if labelled:
            node.create_subscription(Image, topic("semantic/image"), self._label_image, qos)
        node.create_subscription(CameraInfo, topic("rgb/camera_info"), self._camera_info, qos)
        topics = {n: node.resolve_topic_name(topic(f"{n}/image")) for n in names}
        topics["camera_info"] = node.resolve_topic_name(topic("rgb/camera_info"))
        self._count_gaps = forwarded_by is None
        topics.update({n: node.resolve_topic_name(t) for n, t in (extra_topics or {}).items()})
        self.watch = InputWatch(topics, log, hints, apart=frozenset({"semantic"}))
        self.gaps = {name: StreamGaps() for name in [*names, "camera_info"]}
        self._loss_logged_at: float | None = None
        self._busy_logged = False
        profile = os.environ.get(PROFILE_ENV)
        self.socket_advice = socket_buffer_advice(Path(profile) if profile else None)
        if self.socket_advice is not None:  # once: a host setting, not a stream's state
            log(self.socket_advice)

    def _image(self, index: int, name: str, msg: Any) -> None:
        if index == 0:
            self.colour_rate.tick()
        self.watch.tick(name)
        self._count_gap(name, msg)
        self.assembler.image(index, msg)

    def _label_image(self, msg: Any) -> None:
        self.watch.tick("semantic")
        self._count_gap("semantic", msg)
        self.assembler.label_image(msg)

    def _camera_info(self, msg: Any) -> None:
        self.watch.tick("camera_info")
        self._count_gap("camera_info", msg)
        self.assembler.camera_info(msg)

    def _count_gap(self, name: str, msg: Any) -> None:
        if not self._count_gaps:
            return
        report = self.gaps[name].add(stamp_to_ns(msg.header.stamp))
        if report is not None:
            self._log_loss(name, report)

    def _log_loss(self, name: str, report: GapReport) -> None:
        """The first loss at once, later ones at most every few seconds, with the running totals."""
        now = time.monotonic()
        if self._loss_logged_at is not None and now - self._loss_logged_at < _LOSS_LOG_S:
            return
        self._loss_logged_at = now
        totals = ", ".join(f"{self.watch.topics[n]} {g.lost}" for n, g in self.gaps.items() if g.lost)
        self.log(
            f"{report.lost} frame(s) of {self.watch.topics[name]} never arrived (a stamp gap of "
            f"{report.gap_ns / 1e6:.0f} ms at a period of {report.period_ns / 1e6:.1f} ms); lost so far: {totals} "
            "(counted in /diagnostics as frames_lost and lost[...]; see input_qos and the transport in the README)"
        )

    def silence(self, stale_s: float, nothing: str) -> tuple[list[str], tuple[int, str] | None]:
        """The inputs silent for ``stale_s`` s of idle time, and (level, message) when that says something.

        ``nothing`` names what is missing in the message (e.g. "no frames", "nothing mapped"). A busy
        node (a frame in work for longer than ``stale_s``) says so, with its processing rate, and
        judges only the inputs it works without (labels).
        """
        idle_since = self.activity.idle_since()
        if idle_since is None:
            return self._busy_silence(stale_s)
        silent = self.watch.silent(stale_s, idle_since)
        if self.watch.all_silent(stale_s, idle_since):
            last = self.colour_rate.last
            waited = "yet" if last is None else f"for {self.colour_rate.idle_s():.0f} s"
            return silent, (WARN, f"no input {waited}: waiting for {', '.join(self.watch.topics.values())}")
        waited_for = [n for n in silent if n not in self.watch.apart]
        if waited_for:
            names = ", ".join(self.watch.topics[n] for n in waited_for)
            return silent, (WARN, f"{nothing}: {names} silent while the others arrive")
        if silent:
            return silent, (WARN, self._without_message(silent))
        return silent, None

    def _busy_silence(self, stale_s: float) -> tuple[list[str], tuple[int, str] | None]:
        """:meth:`silence` while a frame is in work: the inputs it works without, else how long it is busy."""
        silent = self.watch.silent_apart(stale_s)
        if silent:
            return silent, (WARN, self._without_message(silent))
        busy_s = self.activity.busy_s()
        return [], None if busy_s <= stale_s else (OK, self._busy_message(busy_s))

    def _without_message(self, silent: list[str]) -> str:
        names = ", ".join(self.watch.topics[n] for n in silent)
        return f"no labels: {names} silent while the frames arrive (tracking and mapping go on, without classes)"

    def _busy_message(self, busy_s: float) -> str:
        rate = self.activity.rate_hz()
        text = (
            f"busy: working on a frame for {busy_s:.0f} s (processing {rate:.3g} frames/s); "
            "inputs are judged silent only while the node waits"
        )
        if not self._busy_logged:
            self._busy_logged = True
            self.logger.info(text)
        return text

    def counts(self, pipeline_dropped: int) -> dict[str, str]:
        """The input counts for /diagnostics (``pipeline_dropped``: frames the pipeline dropped).

        ``frames_in`` counts colour images that arrived; ``frames_lost`` those that never did (gaps in
        the colour stamps), ``lost[...]`` the same for the other inputs (neither for forwarded frames,
        whose gaps are frames the tracker did not accept).
        """
        a = self.assembler
        counts = {
            "frames_in": str(a.colour_in),
            "frames_lost": str(self.gaps["rgb"].lost),
            "frames_dropped": str(pipeline_dropped + a.colour_dropped),
            "frames_rejected": str(a.frames_rejected),
            "frames_waiting": str(a.frames_waiting),
            **{f"lost[{self.watch.topics[n]}]": str(g.lost) for n, g in self.gaps.items() if n != "rgb"},
        }
        if not self._count_gaps:
            counts = {k: v for k, v in counts.items() if k != "frames_lost" and not k.startswith("lost[")}
        return counts

    def sizes(self) -> dict[str, str]:
        """The input and processing sizes for /diagnostics ("n/a" before the first frame)."""
        a = self.assembler

        def text(size: tuple[int, int] | None) -> str:
            return "n/a" if size is None else f"{size[0]}x{size[1]}"

        return {
            "input_size": text(a.input_size),
            "processing_size": text(a.processing_size),
            "downscale": "auto" if a.downscale == AUTO_DOWNSCALE else f"{a.downscale:g}",
        }

    def transport(self) -> dict[str, str]:
        """Whether the host's socket buffers hold what the DDS profile asks for (frames from other computers)."""
        short = self.socket_advice is not None
        return {"socket_buffers": "too small for the DDS profile: see the log for the sysctl" if short else "ok"}

    def silent_names(self, silent: list[str]) -> str:
        """The topics of ``silent`` for /diagnostics ("none" when empty)."""
        return ", ".join(self.watch.topics[n] for n in silent) or "none"

    def reset(self) -> None:
        """Forget queued messages and silence reports (after a SLAM reset)."""
        self.assembler.reset()
        self.watch.reset()
        for gaps in self.gaps.values():
            gaps.reset()
