"""The camera topics of a node: subscriptions, frame assembly, silence watch and their live parameters.

Shared by ``tracking_node`` and a standalone ``mapping_node``: both subscribe ``{rgb,depth,semantic}/image``
and ``rgb/camera_info`` with the input QoS, synchronise them into frames (:class:`FrameAssembler`) and
report inputs that stay silent (:class:`InputWatch`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image

from sgs_slam_core.frame import Frame
from sgs_slam_ros.diagnostics import WARN, RateMeter
from sgs_slam_ros.frames import FrameAssembler
from sgs_slam_ros.inputs import InputWatch
from sgs_slam_ros.params import NodeParams
from sgs_slam_ros.qos import input_qos

__all__ = ["CameraInputs"]


class CameraInputs:
    """Subscribes a node's camera topics and hands each synchronised frame to ``on_frame``.

    ``extra_topics``: further inputs the node subscribes itself (name -> topic relative to the node),
    watched for silence too (the node calls ``watch.tick(name)``); ``hints``: a sentence per input
    added to its "silent" log line.
    """

    def __init__(
        self,
        node: Node,
        params: NodeParams,
        on_frame: Callable[[Frame], None],
        extra_topics: dict[str, str] | None = None,
        hints: dict[str, str] | None = None,
    ) -> None:
        log = node.get_logger().warn
        self.assembler = FrameAssembler(
            params["use_semantics"], params["sync_queue_size"], round(params["sync_slop_s"] * 1e9),
            params["depth_scale"], on_frame, log,
        )  # fmt: skip
        params.on_change["sync_slop_s"] = self.assembler.set_slop
        params.on_change["depth_scale"] = lambda v: setattr(self.assembler, "depth_scale", v)
        self.colour_rate = RateMeter()
        qos = input_qos(params["input_qos"], params["sync_queue_size"])
        names = ["rgb", "depth", *(["semantic"] if params["use_semantics"] else [])]
        for i, name in enumerate(names):
            node.create_subscription(Image, f"{name}/image", lambda msg, i=i, n=name: self._image(i, n, msg), qos)
        node.create_subscription(CameraInfo, "rgb/camera_info", self._camera_info, qos)
        topics = {n: node.resolve_topic_name(f"{n}/image") for n in names}
        topics["camera_info"] = node.resolve_topic_name("rgb/camera_info")
        topics.update({n: node.resolve_topic_name(t) for n, t in (extra_topics or {}).items()})
        self.watch = InputWatch(topics, log, hints)

    def _image(self, index: int, name: str, msg: Any) -> None:
        if index == 0:
            self.colour_rate.tick()
        self.watch.tick(name)
        self.assembler.image(index, msg)

    def _camera_info(self, msg: Any) -> None:
        self.watch.tick("camera_info")
        self.assembler.camera_info(msg)

    def silence(self, stale_s: float, nothing: str) -> tuple[list[str], tuple[int, str] | None]:
        """The inputs silent for ``stale_s`` s, and (WARN, message) when that stops the node's work.

        ``nothing`` names what is missing in the message (e.g. "no frames", "nothing mapped").
        """
        silent = self.watch.silent(stale_s)
        if self.watch.all_silent(stale_s):
            last = self.colour_rate.last
            waited = "yet" if last is None else f"for {self.colour_rate.idle_s():.0f} s"
            return silent, (WARN, f"no input {waited}: waiting for {', '.join(self.watch.topics.values())}")
        if silent:
            names = ", ".join(self.watch.topics[n] for n in silent)
            return silent, (WARN, f"{nothing}: {names} silent while the others arrive")
        return silent, None

    def counts(self, pipeline_dropped: int) -> dict[str, str]:
        """The input counts for /diagnostics (``pipeline_dropped``: frames the pipeline dropped)."""
        a = self.assembler
        return {
            "frames_in": str(a.colour_in),
            "frames_dropped": str(pipeline_dropped + a.colour_dropped),
            "frames_rejected": str(a.frames_rejected),
            "frames_waiting": str(a.frames_waiting),
        }

    def silent_names(self, silent: list[str]) -> str:
        """The topics of ``silent`` for /diagnostics ("none" when empty)."""
        return ", ".join(self.watch.topics[n] for n in silent) or "none"

    def reset(self) -> None:
        """Forget queued messages and silence reports (after a SLAM reset)."""
        self.assembler.reset()
        self.watch.reset()
