"""``/tf`` and ``/tf_static`` for the camera pose (REP-105), without tf2_ros (not on PyPI).

The transforms, by configuration (``base_frame`` / ``odom_frame`` parameters):

- neither: ``map -> camera`` (the tracked pose);
- ``base_frame``: ``map -> base`` (pose times the inverse mount) and static ``base -> camera``
  (``camera_mount``; left to the camera driver with ``publish_camera_mount:=false``, as realsense-ros
  publishes ``camera_link -> camera_color_optical_frame`` itself);
- both: static ``map -> odom`` (identity: the map frame never jumps, SGS-SLAM has no loop closure),
  ``odom -> base`` and static ``base -> camera``; the tracker is then the odometry source.

``tf2_msgs`` is generated at set-up from the rosidl wheels (``make setup``, see vendor/tf2_msgs);
without it the publisher logs once and stays off. QoS as tf2_ros's broadcasters: ``/tf`` reliable,
volatile, depth 100; ``/tf_static`` reliable, transient local, depth 1, all static transforms in one
message.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from geometry_msgs.msg import TransformStamped
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from msg_adapters import c2w_to_pose
from sgs_slam_ros.messages import header

__all__ = ["TF_QOS", "TF_STATIC_QOS", "TfFrames", "TfPublisher", "transform_msg"]

TF_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
TF_STATIC_QOS = QoSProfile(
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    history=HistoryPolicy.KEEP_LAST,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)


@dataclass(frozen=True)
class TfFrames:
    """Frame ids and the camera mount of the published tree."""

    map_frame: str
    base_frame: str = ""  # '' = no body frame
    odom_frame: str = ""  # '' = no odom frame (only used with base_frame)
    mount: np.ndarray | None = None  # [4, 4] camera optical frame in base_frame
    publish_mount: bool = True  # send base_frame -> camera on /tf_static


def transform_msg(pose: np.ndarray, stamp_ns: int, parent: str, child: str) -> TransformStamped:
    """TransformStamped of the pose [4, 4] of ``child`` in ``parent``."""
    f = c2w_to_pose(pose, stamp_ns, parent)["pose"]
    msg = TransformStamped(header=header(stamp_ns, parent), child_frame_id=child)
    t, q = msg.transform.translation, msg.transform.rotation
    t.x, t.y, t.z = f["position"]["x"], f["position"]["y"], f["position"]["z"]
    q.x, q.y, q.z, q.w = f["orientation"]["x"], f["orientation"]["y"], f["orientation"]["z"], f["orientation"]["w"]
    return msg


def _tf_message_class() -> type | None:
    try:
        return importlib.import_module("tf2_msgs.msg").TFMessage
    except ImportError:
        return None


class TfPublisher:
    """Publishes the camera pose on /tf (and the fixed part of the tree on /tf_static)."""

    def __init__(self, node: Node, frames: TfFrames, warn: Callable[[str], None]) -> None:
        self.frames = frames
        self.tf_message = _tf_message_class()
        self.available = self.tf_message is not None
        self._static_for: str | None = None  # camera frame the static transforms were sent for
        if not self.available:
            warn("tf2_msgs is not installed, so /tf is off (make setup builds it from vendor/tf2_msgs)")
            return
        self.pub = node.create_publisher(self.tf_message, "/tf", TF_QOS)
        self.static_pub = node.create_publisher(self.tf_message, "/tf_static", TF_STATIC_QOS)

    def chain(self, c2w: np.ndarray, stamp_ns: int, camera: str) -> tuple[list, list]:
        """(dynamic, static) transforms for the camera pose ``c2w`` [4, 4] in the map frame."""
        f = self.frames
        if not f.base_frame:
            return [transform_msg(c2w, stamp_ns, f.map_frame, camera)], []
        mount = np.eye(4) if f.mount is None else f.mount
        body = c2w @ np.linalg.inv(mount)
        static = [transform_msg(mount, stamp_ns, f.base_frame, camera)] if f.publish_mount else []
        if not f.odom_frame:
            return [transform_msg(body, stamp_ns, f.map_frame, f.base_frame)], static
        static.append(transform_msg(np.eye(4), stamp_ns, f.map_frame, f.odom_frame))
        return [transform_msg(body, stamp_ns, f.odom_frame, f.base_frame)], static

    def publish(self, c2w: np.ndarray, stamp_ns: int, camera: str) -> None:
        """Publish the tree for one tracked pose (static transforms once per camera frame id)."""
        if not self.available:
            return
        dynamic, static = self.chain(c2w, stamp_ns, camera)
        if static and self._static_for != camera:  # one message holds every static transform (latched)
            self.static_pub.publish(self.tf_message(transforms=static))
            self._static_for = camera
        self.pub.publish(self.tf_message(transforms=dynamic))
