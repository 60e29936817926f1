"""Tracked frames forwarded at the processing size: what a mapping_node on another computer maps.

Between computers the camera topics are the heavy part of the traffic (a 640x480 RGB-D stream at
30 Hz is about 46 MB/s). A tracking_node with ``forward_frames`` publishes each frame it accepted
(tracked, not failed, not lost) as it tracked it: colour (rgb8), depth (32FC1 metres: no depth scale
to agree on), its camera_info, and label images at the same size when it has a label source, all
with the colour image's stamp, on ``~/frames/{rgb,depth,semantic}/image`` and
``~/frames/rgb/camera_info``. A mapping_node with ``frame_source:=tracking_node`` subscribes those
instead of the camera's and pairs each frame with the pose of the same stamp.
"""

from __future__ import annotations

import threading

import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image

from sgs_slam_core.frame import Frame
from sgs_slam_ros.messages import camera_info_msg, image_msg
from sgs_slam_ros.qos import output_qos

__all__ = ["FORWARD_PREFIX", "FrameForwarder", "forwarded_topic"]

FORWARD_PREFIX = "frames"  # the forwarded topics live under tracking_node's ~/frames/
_DEPTH = 10  # messages kept per forwarded topic for a slow subscriber (reliable)


def forwarded_topic(node_name: str, topic: str) -> str:
    """Where ``node_name``'s forwarded copy of ``topic`` (e.g. ``rgb/image``) is, relative to a node's namespace."""
    return f"{node_name}/{FORWARD_PREFIX}/{topic}"


class FrameForwarder:
    """Publishes accepted frames and label images at the processing size; counts what it sent."""

    def __init__(self, node: Node, labels: bool) -> None:
        """``labels``: label images are forwarded too (the node has a label source)."""
        qos = output_qos(_DEPTH)
        prefix = f"~/{FORWARD_PREFIX}"
        self._rgb = node.create_publisher(Image, f"{prefix}/rgb/image", qos)
        self._depth = node.create_publisher(Image, f"{prefix}/depth/image", qos)
        self._info = node.create_publisher(CameraInfo, f"{prefix}/rgb/camera_info", qos)
        self._labels = node.create_publisher(Image, f"{prefix}/semantic/image", qos) if labels else None
        self._lock = threading.Lock()  # frames come from the tracking thread, labels from the executor
        self.frames_sent = 0
        self.labels_sent = 0
        self.bytes_sent = 0  # image payload bytes (colour, depth, labels)
        self.last_stamp_ns: int | None = None  # of the last frame forwarded
        self._last: tuple[CameraInfo, Image, Image] | None = None

    def frame(self, frame: Frame, frame_id: str) -> None:
        """Forward an accepted frame: colour, depth and camera_info with its stamp."""
        stamp = frame.stamp_ns
        msgs = (
            camera_info_msg(frame.intrinsics, stamp, frame_id),
            image_msg(frame.depth, "32FC1", stamp, frame_id),
            image_msg(frame.rgb, "rgb8", stamp, frame_id),
        )
        with self._lock:
            self._last, self.last_stamp_ns = msgs, stamp
            self.frames_sent += 1
            self.bytes_sent += len(msgs[1].data) + len(msgs[2].data)
        self._publish(msgs)

    def republish(self) -> None:
        """Send the last forwarded frame again (a lockstep mapper that matched late never got it)."""
        with self._lock:
            msgs = self._last
        if msgs is not None:
            self._publish(msgs)

    def reset(self) -> None:
        """Forget the last frame (a new run); the counts go on."""
        with self._lock:
            self._last, self.last_stamp_ns = None, None

    def _publish(self, msgs: tuple[CameraInfo, Image, Image]) -> None:
        info, depth, rgb = msgs
        self._info.publish(info)
        self._depth.publish(depth)
        self._rgb.publish(rgb)

    def labels(self, stamp_ns: int, labels: np.ndarray, frame_id: str) -> None:  # labels [H, W] class ids
        """Forward a label image at the processing size (16UC1 class ids)."""
        if self._labels is None:
            return
        msg = image_msg(labels.astype(np.uint16), "16UC1", stamp_ns, frame_id)
        self._labels.publish(msg)
        with self._lock:
            self.labels_sent += 1
            self.bytes_sent += len(msg.data)

    def counts(self) -> dict[str, str]:
        """What was forwarded, for /diagnostics and the final counts."""
        with self._lock:
            return {
                "frames_forwarded": str(self.frames_sent),
                "labels_forwarded": str(self.labels_sent),
                "forwarded_mb": f"{self.bytes_sent / 1e6:.1f}",
            }
