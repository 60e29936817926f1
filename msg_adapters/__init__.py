"""ROS message <-> numpy adapters written against field names (no rclpy import).

The same functions read rclpy messages, rosbags messages and mcap-ros2 decoded messages; writers
return plain field values (``bytes`` for ``data``: assigning a numpy array to an rclpy message's
``data`` is ~200x slower) that the ROS layer or the bag writer puts into its own message class.
"""

from msg_adapters.camera_info import camera_info_fields, camera_info_to_intrinsics
from msg_adapters.errors import AdapterError
from msg_adapters.image import (
    ENCODINGS,
    MAX_LABEL_ID,
    depth_from_image,
    image_fields,
    image_to_numpy,
    labels_from_image,
    rgb_from_image,
)
from msg_adapters.pointcloud import (
    GAUSSIAN_FIELDS,
    POINT_DTYPE,
    gaussians_from_cloud,
    gaussians_to_cloud,
    pack_rgb,
    pointcloud_fields,
    pointcloud_to_numpy,
    unpack_rgb,
)
from msg_adapters.pose import c2w_to_pose, pose_to_c2w
from msg_adapters.stamps import ns_to_stamp, stamp_to_ns
from msg_adapters.sync import ApproximateSync

__all__ = [
    "ENCODINGS",
    "GAUSSIAN_FIELDS",
    "MAX_LABEL_ID",
    "POINT_DTYPE",
    "AdapterError",
    "ApproximateSync",
    "c2w_to_pose",
    "camera_info_fields",
    "camera_info_to_intrinsics",
    "depth_from_image",
    "gaussians_from_cloud",
    "gaussians_to_cloud",
    "image_fields",
    "image_to_numpy",
    "labels_from_image",
    "ns_to_stamp",
    "pack_rgb",
    "pointcloud_fields",
    "pointcloud_to_numpy",
    "pose_to_c2w",
    "rgb_from_image",
    "stamp_to_ns",
    "unpack_rgb",
]
