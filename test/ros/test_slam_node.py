"""slam_node in-process: a lockstep replay of the tiny synthetic scene, outputs, services, bad input."""

import dataclasses

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Path
from sensor_msgs.msg import Image, PointCloud2
from std_srvs.srv import SetBool, Trigger

from msg_adapters import image_to_numpy, pointcloud_to_numpy, pose_to_c2w
from sgs_slam_core.metrics import ate
from sgs_slam_ros.slam_node import build_slam_nodes

from ..polling import wait_for
from .helpers import Feeder, Spinner, new_context, node_params, shut_down, tiny_frames

pytestmark = pytest.mark.ros


@pytest.fixture(scope="module")
def tiny(tiny_scene):
    return tiny_frames(tiny_scene)


@pytest.fixture
def system(tmp_path):
    ctx = new_context()
    nodes = build_slam_nodes(context=ctx, parameter_overrides=node_params(map_path=str(tmp_path / "m.sgsmap")))
    feeder = Feeder(ctx)
    received = {"path": [], "points": [], "color": [], "labels": [], "depth": [], "diag": []}
    feeder.create_subscription(Path, "/tracking_node/path", received["path"].append, 10)
    feeder.create_subscription(PointCloud2, "/mapping_node/points", received["points"].append, 10)
    for key, topic in (("color", "color"), ("labels", "labels"), ("depth", "depth")):
        feeder.create_subscription(Image, f"/mapping_node/render/{topic}", received[key].append, 10)
    feeder.create_subscription(DiagnosticArray, "/diagnostics", received["diag"].append, 50)
    spinner = Spinner(ctx, [*nodes, feeder])
    assert wait_for(feeder.connected, 10.0), "slam_node did not subscribe"
    yield nodes, feeder, received
    shut_down(ctx, [*nodes, feeder], spinner)


def call(node, srv_type, name, request, timeout=30.0):
    client = node.create_client(srv_type, name)
    assert client.wait_for_service(timeout_sec=10.0), name
    future = client.call_async(request)
    assert wait_for(future.done, timeout), f"{name} did not answer"
    return future.result()


def play(feeder, frames, timeout=60.0):
    for f in frames:
        feeder.publish(f)
        assert wait_for(lambda f=f: f.stamp_ns in feeder.poses, timeout), f"no pose for frame {f.index}"


def test_lockstep_replay_outputs_and_services(system, tiny):
    nodes, feeder, received = system
    mapping = nodes[1]
    play(feeder, tiny)
    # a pose per frame, close to the ground truth
    est = np.stack([pose_to_c2w(feeder.poses[f.stamp_ns]) for f in tiny])
    gt = np.stack([f.gt_c2w for f in tiny])
    assert ate(est, gt).rmse < 0.03
    assert feeder.poses[tiny[0].stamp_ns].header.frame_id == "map"
    assert wait_for(lambda: received["path"] and len(received["path"][-1].poses) == len(tiny), 10.0)
    assert len(received["path"][0].poses) < len(received["path"][-1].poses)  # the path grows
    # point cloud with the documented fields and labels
    assert mapping.pipeline.wait_idle(30.0)
    count = mapping.pipeline.slam.num_gaussians
    assert wait_for(lambda: received["points"] and received["points"][-1].width == count, 10.0)
    pts = pointcloud_to_numpy(received["points"][-1])
    assert pts.dtype.names == ("x", "y", "z", "rgb", "label")
    assert len(np.unique(pts["label"])) >= 3
    # renders of the right size and encoding
    assert wait_for(lambda: received["color"] and received["labels"] and received["depth"], 10.0)
    color, labels, depth = received["color"][-1], received["labels"][-1], received["depth"][-1]
    assert (color.encoding, labels.encoding, depth.encoding) == ("rgb8", "16UC1", "32FC1")
    assert image_to_numpy(color).shape == (48, 64, 3) and image_to_numpy(depth).shape == (48, 64)
    assert len(np.unique(image_to_numpy(labels))) >= 3
    # save, then load gives the same Gaussian count; reset empties the map
    assert call(feeder, Trigger, "/mapping_node/save_map", Trigger.Request()).success
    assert call(feeder, Trigger, "/mapping_node/reset", Trigger.Request()).success
    assert mapping.pipeline.slam.num_gaussians == 0
    response = call(feeder, Trigger, "/mapping_node/load_map", Trigger.Request())
    assert response.success and mapping.pipeline.slam.num_gaussians == count, response.message
    # the diagnostics report progress
    assert wait_for(lambda: any(s.name.endswith("tracking_node") for a in received["diag"] for s in a.status), 5.0)


def test_pause_stops_pose_output(system, tiny):
    _, feeder, _ = system
    play(feeder, tiny[:2])
    assert call(feeder, SetBool, "/mapping_node/pause", SetBool.Request(data=True)).success
    feeder.publish(tiny[2])
    assert not wait_for(lambda: tiny[2].stamp_ns in feeder.poses, 2.0)
    assert call(feeder, SetBool, "/mapping_node/pause", SetBool.Request(data=False)).success
    play(feeder, tiny[3:4])


def test_bad_input_is_counted_and_the_node_keeps_running(system, tiny):
    nodes, feeder, received = system
    tracking = nodes[0]
    play(feeder, tiny[:2])
    bad = tiny[2]
    feeder.publish(bad, depth_encoding="32FC1", semantic=True)  # accepted: 32FC1 metres is valid
    assert wait_for(lambda: bad.stamp_ns in feeder.poses, 30.0)
    wrong = dataclasses.replace(tiny[3])
    stamp = wrong.stamp_ns
    feeder.pubs["/depth/image"].publish(feeder_image(wrong.rgb, "rgb8", stamp))  # depth with a colour encoding
    feeder.pubs["/rgb/image"].publish(feeder_image(wrong.rgb, "rgb8", stamp))
    feeder.pubs["/semantic/image"].publish(feeder_image(wrong.labels.astype("uint16"), "16UC1", stamp))
    assert wait_for(lambda: tracking.assembler.rejected["wrong encoding or bad image"] == 1, 5.0)
    old = dataclasses.replace(tiny[1], stamp_ns=tiny[1].stamp_ns)  # stamps going backwards
    feeder.publish(old)
    assert wait_for(lambda: tracking.assembler.rejected["stamps went backwards"] == 1, 5.0)

    def diag_drops():
        values = [
            {kv.key: kv.value for kv in s.values}
            for a in received["diag"]
            for s in a.status
            if s.name.endswith("tracking_node")
        ]
        return values and int(values[-1]["frames_rejected"]) >= 2

    assert wait_for(diag_drops, 5.0)
    play(feeder, tiny[4:5])  # still running


def feeder_image(arr, encoding, stamp):
    from sgs_slam_ros.messages import image_msg

    return image_msg(arr, encoding, stamp, "camera_color_optical_frame")


def set_remote(feeder, node_name, **values):
    """Set parameters through the node's parameter service, as ``ros2 param set`` does."""
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient

    client = AsyncParameterClient(feeder, node_name)
    assert client.wait_for_services(timeout_sec=10.0)
    future = client.set_parameters([Parameter(k.replace("__", "."), value=v) for k, v in values.items()])
    assert wait_for(future.done, 10.0)
    return [r.successful for r in future.result().results]


def test_edit_services_remove_lock_and_undo(system, tiny):
    nodes, feeder, _ = system
    slam = nodes[1].pipeline.slam
    clouds = []
    feeder.create_subscription(PointCloud2, "/mapping_node/gaussians", clouds.append, 10)
    play(feeder, tiny[:6])
    pipeline = nodes[1].pipeline  # label images are fused apart from their frames: wait for the last one too
    assert wait_for(lambda: pipeline.stats.labels.labels_in == 6 and pipeline.wait_idle(1.0), 30.0)
    table = int((slam.gaussians.labels == 7).sum())
    assert table > 20

    nothing = call(feeder, Trigger, "/mapping_node/apply_edit", Trigger.Request())
    assert not nothing.success and "nothing to apply" in nothing.message
    assert set_remote(feeder, "/mapping_node", edit__remove_labels=["table"]) == [True]
    done = call(feeder, Trigger, "/mapping_node/apply_edit", Trigger.Request())
    assert done.success and f"remove: {table} Gaussians of classes [7]" in done.message, done.message
    assert int((slam.gaussians.labels == 7).sum()) == 0
    assert wait_for(lambda: clouds and not np.any(pointcloud_to_numpy(clouds[-1])["label"] == 7), 10.0)

    play(feeder, tiny[6:])  # the table is seen again but stays removed
    assert nodes[1].pipeline.wait_idle(30.0)
    assert int((slam.gaussians.labels == 7).sum()) == 0

    undone = call(feeder, Trigger, "/mapping_node/undo_edit", Trigger.Request())
    assert undone.success and int((slam.gaussians.labels == 7).sum()) == table and not slam.locked_labels
    again = call(feeder, Trigger, "/mapping_node/undo_edit", Trigger.Request())
    assert not again.success and "no edit to undo" in again.message

    assert set_remote(
        feeder, "/mapping_node", edit__remove_labels=[""], edit__move_label="7", edit__translation=[0.1, 0.0]
    ) == [True, True, True]
    bad = call(feeder, Trigger, "/mapping_node/apply_edit", Trigger.Request())
    assert not bad.success and "edit.translation needs 3 finite numbers" in bad.message
    assert set_remote(feeder, "/mapping_node", edit__translation=[0.1, 0.0, 0.0]) == [True]
    moved = call(feeder, Trigger, "/mapping_node/apply_edit", Trigger.Request())
    assert moved.success and "move" in moved.message and slam.locked_labels == {7}
