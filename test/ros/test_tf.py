"""/tf and /tf_static from slam_node, read by an in-process subscriber; the z-up (gravity-aligned) map."""

import math

import numpy as np
import pytest
from tf2_msgs.msg import TFMessage

from msg_adapters import pose_to_c2w, stamp_to_ns
from sgs_slam_core.geometry.gravity import pose_from_xyz_rpy
from sgs_slam_ros.slam_node import build_slam_nodes
from sgs_slam_ros.tf import TF_QOS, TF_STATIC_QOS

from ..polling import wait_for
from .helpers import Feeder, Spinner, new_context, node_params, shut_down, tiny_frames

pytestmark = pytest.mark.ros

# type hash of tf2_msgs/msg/TFMessage in ROS 2 Jazzy: equal hashes mean RViz and tf2_ros accept our /tf
JAZZY_TF_HASH = "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087"
CAM = "test_cam_color_optical_frame"


def tf_matrix(t) -> np.ndarray:  # TransformStamped -> [4, 4] pose of child in parent
    tr, q = t.transform.translation, t.transform.rotation

    class _P:  # pose_to_c2w reads position / orientation by field name
        position, orientation = tr, q

    return pose_to_c2w(_P)


def up_angle_deg(c2w_a: np.ndarray, c2w_b: np.ndarray) -> float:
    """Angle between the two worlds' z axes as seen from the camera (equal poses up to yaw and x/y: 0)."""
    a, b = c2w_a[:3, :3].T @ [0.0, 0.0, 1.0], c2w_b[:3, :3].T @ [0.0, 0.0, 1.0]
    return math.degrees(math.acos(np.clip(a @ b, -1.0, 1.0)))


def replay(tiny_scene, count, **params):
    """Run slam_node on ``count`` frames; returns (frames, poses by stamp, /tf messages, /tf_static messages)."""
    frames = tiny_frames(tiny_scene)[:count]
    ctx = new_context()
    nodes = build_slam_nodes(context=ctx, parameter_overrides=node_params(**params))
    feeder = Feeder(ctx)
    tf, static = [], []
    feeder.create_subscription(TFMessage, "/tf", tf.append, TF_QOS)
    spinner = Spinner(ctx, [*nodes, feeder])
    try:
        assert wait_for(feeder.connected, 10.0), "slam_node did not subscribe"
        assert wait_for(lambda: feeder.count_subscribers("/tf") >= 1 and feeder.count_publishers("/tf") >= 1, 10.0)
        for f in frames:
            feeder.publish(f, frame_id=CAM)
            assert wait_for(lambda f=f: f.stamp_ns in feeder.poses, 60.0), f"no pose for frame {f.index}"
        expected = count if params.get("publish_tf", True) else 0
        assert wait_for(lambda: sum(len(m.transforms) for m in tf) >= expected, 10.0)
        # /tf_static is latched: a subscriber that comes late still gets it
        feeder.create_subscription(TFMessage, "/tf_static", static.append, TF_STATIC_QOS)
        if params.get("base_frame"):
            assert wait_for(lambda: static, 10.0), "no /tf_static"
        info = feeder.get_publishers_info_by_topic("/tf")
        assert info and str(info[0].topic_type_hash) == JAZZY_TF_HASH
        poses = {stamp: pose_to_c2w(msg) for stamp, msg in feeder.poses.items()}
        return frames, poses, tf, static
    finally:
        shut_down(ctx, [*nodes, feeder], spinner)


def test_tf_map_to_camera_matches_every_pose_in_a_levelled_map(tiny_scene):
    frames, poses, tf, _ = replay(tiny_scene, 4)
    transforms = [t for m in tf for t in m.transforms]
    assert [stamp_to_ns(t.header.stamp) for t in transforms] == [f.stamp_ns for f in frames]  # one per pose
    for t in transforms:
        assert (t.header.frame_id, t.child_frame_id) == ("map", CAM)  # the input's frame id
        np.testing.assert_allclose(tf_matrix(t), poses[stamp_to_ns(t.header.stamp)], atol=1e-6)
    # map_alignment:=floor (the default): z up along the room's, origin on the floor (the scene's z = 0)
    for f in frames:
        est = poses[f.stamp_ns]
        assert up_angle_deg(est, f.gt_c2w) < 1.5
        assert abs(est[2, 3] - f.gt_c2w[2, 3]) < 0.05
    first = poses[frames[0].stamp_ns]
    assert np.allclose(first[:2, 3], 0.0)  # above the origin


def test_odom_and_base_chain_with_a_static_camera_mount(tiny_scene):
    mount = [0.1, 0.0, 1.2, -math.pi / 2, 0.0, -math.pi / 2]  # camera 1.2 m up on the body, looking along x
    frames, poses, tf, static = replay(
        tiny_scene, 3, base_frame="base_link", odom_frame="odom", camera_mount=mount, map_alignment="mount"
    )
    mount_pose = pose_from_xyz_rpy(mount)
    fixed = {(t.header.frame_id, t.child_frame_id): tf_matrix(t) for m in static for t in m.transforms}
    assert set(fixed) == {("base_link", CAM), ("map", "odom")}
    np.testing.assert_allclose(fixed["base_link", CAM], mount_pose, atol=1e-6)
    np.testing.assert_allclose(fixed["map", "odom"], np.eye(4), atol=1e-9)
    dynamic = [t for m in tf for t in m.transforms]
    assert {(t.header.frame_id, t.child_frame_id) for t in dynamic} == {("odom", "base_link")}
    for t in dynamic:  # map -> odom -> base_link -> camera is the tracked camera pose
        chained = fixed["map", "odom"] @ tf_matrix(t) @ fixed["base_link", CAM]
        np.testing.assert_allclose(chained, poses[stamp_to_ns(t.header.stamp)], atol=1e-6)
    # map_alignment:=mount: the map is the body's first pose, so the first camera pose is the mount itself
    np.testing.assert_allclose(poses[frames[0].stamp_ns], mount_pose, atol=1e-9)


def test_optical_map_frame_is_still_available_and_tf_can_be_off(tiny_scene):
    frames, poses, tf, _ = replay(tiny_scene, 2, map_alignment="optical", publish_tf=False)
    np.testing.assert_allclose(poses[frames[0].stamp_ns], np.eye(4), atol=1e-12)
    assert not tf
