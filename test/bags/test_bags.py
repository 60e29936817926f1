"""Dataset folders -> MCAP bags -> frames, read back with rosbags AND mcap; corrupt bags; run on bags."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from bags import BagDataset, BagError, convert, open_bag
from bags.cli import main as bag_main
from bags.info import bag_info
from msg_adapters import depth_from_image, labels_from_image, pose_to_c2w, rgb_from_image, stamp_to_ns
from sgs_slam_core.cli import main as slam_main
from sgs_slam_core.datasets import DatasetOptions, detect_format, open_dataset
from sgs_slam_core.metrics import read_tum_trajectory

from ..conftest import FAST_SLAM
from ..datasets.test_replica_scannet import scannet_scene, sgs_layout  # noqa: F401 - fixture
from ..datasets.test_tum import write_tum

pytestmark = pytest.mark.slow  # end to end: left out of make test-fast


def decoded_with_mcap(bag):
    out = {}
    with open(next(bag.glob("*.mcap")), "rb") as f:
        for _, channel, _, msg in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            out.setdefault(channel.topic, []).append(msg)
    return out


def decoded_with_rosbags(bag):
    out = {}
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        for conn, _, raw in reader.messages():
            out.setdefault(conn.topic, []).append(reader.deserialize(raw, conn.msgtype))
    return out


def assert_bag_matches(dataset, bag):
    frames = [dataset[i] for i in range(len(dataset))]
    for decoded in (decoded_with_mcap(bag), decoded_with_rosbags(bag)):
        colors, depths = decoded["/camera/color/image_raw"], decoded["/camera/depth/image_raw"]
        assert len(colors) == len(depths) == len(frames)
        for i, frame in enumerate(frames):
            assert stamp_to_ns(colors[i].header.stamp) == frame.stamp_ns
            assert colors[i].header.frame_id == "camera_color_optical_frame"
            assert np.array_equal(rgb_from_image(colors[i]), frame.rgb)
            assert np.abs(depth_from_image(depths[i]) - frame.depth).max() <= 0.0005 + 1e-6  # millimetres
            if frame.labels is not None:
                assert np.array_equal(labels_from_image(decoded["/camera/semantic/image_raw"][i]), frame.labels)
            if frame.gt_c2w is not None:
                poses = {stamp_to_ns(p.header.stamp): p for p in decoded["/camera/pose"]}
                assert np.allclose(pose_to_c2w(poses[frame.stamp_ns]), frame.gt_c2w, atol=1e-9)
        info = decoded["/camera/color/camera_info"][0]
        assert info.k[0] == pytest.approx(dataset.intrinsics.fx) and info.width == dataset.intrinsics.width


def round_trip(dataset, tmp_path):
    bag = tmp_path / "bag"
    summary = convert(dataset, bag)
    assert summary.frames == len(dataset) and (bag / "metadata.yaml").is_file()
    assert_bag_matches(dataset, bag)
    back = open_bag(bag)
    assert len(back) == len(dataset) and back.intrinsics == dataset.intrinsics
    for i in (0, len(dataset) - 1):
        a, b = dataset[i], back[i]
        assert np.array_equal(a.rgb, b.rgb) and a.stamp_ns == b.stamp_ns
    for ds in (dataset, back):  # ground truth without decoding frames, the same as the frames carry
        for i in range(len(ds)):
            gt, frame_gt = ds.ground_truth(i), ds[i].gt_c2w
            assert (gt is None) == (frame_gt is None) and (gt is None or np.allclose(gt, frame_gt, atol=1e-12))
        assert (a.labels is None) == (b.labels is None) and (a.labels is None or np.array_equal(a.labels, b.labels))
    return bag


def test_synthetic_replica_round_trip_and_metadata(tiny_scene, tmp_path):
    ds = open_dataset(tiny_scene)
    bag = round_trip(ds, tmp_path)
    assert detect_format(bag) == "mcap"
    back = open_bag(bag)
    assert back.label_table == ds.label_table and back.has_ground_truth
    info = bag_info(bag)
    assert {t.name for t in info.topics} >= {"/camera/color/image_raw", "/camera/pose", "/clock"}
    assert json.loads(info.custom["label_table"])["name"] == "synthetic-room"


def test_tum_round_trip(tmp_path):
    root = tmp_path / "rgbd_dataset_freiburg1_desk"
    write_tum(
        root, [1.0, 1.033, 1.066], [1.001, 1.034, 1.067], [(0.9, 0, 0, 0, 0, 0, 0, 1), (1.2, 1, 0, 0, 0, 0, 0, 1)]
    )
    round_trip(open_dataset(root), tmp_path)


def test_replica_round_trip(tmp_path):
    sgs_layout(tmp_path / "replica")
    (tmp_path / "r").mkdir()
    round_trip(open_dataset(tmp_path / "replica"), tmp_path / "r")


def test_scannet_labels_above_255_and_skipped_pose(tmp_path, request):
    scene = request.getfixturevalue("scannet_scene")
    ds = open_dataset(scene)
    assert ds.skipped == 1
    bag = round_trip(ds, tmp_path)
    labels = decoded_with_mcap(bag)["/camera/semantic/image_raw"]
    assert labels[0].encoding == "16UC1" and len(labels) == 3  # the -inf pose frame is not in the bag


@pytest.mark.data
def test_real_tum_sample_converted_and_read_back(tum_teddy, tmp_path):
    ds = open_dataset(tum_teddy, options=DatasetOptions(max_frames=40))
    bag = round_trip(ds, tmp_path)
    back = open_bag(bag)
    assert back.intrinsics.fx == pytest.approx(535.4)
    gt = [back[i].gt_c2w is not None for i in range(len(back))]
    assert not any(gt[:5]) and all(gt[5:])  # frames before the motion capture started carry no pose


def write_foreign_bag(bag: Path) -> list[tuple[np.ndarray, np.ndarray]]:
    """A 3-frame bag as another recorder writes it: bgr8 colour, 32FC1 depth 5 ms late, other topic names."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    from bags import rosbags_messages as rm
    from msg_adapters import camera_info_fields, image_fields
    from sgs_slam_core.geometry import Intrinsics

    ts = get_typestore(Stores.ROS2_JAZZY)
    k = Intrinsics(40.0, 40.0, 15.5, 11.5, 32, 24)
    rng = np.random.default_rng(0)
    frames = [
        (rng.integers(0, 255, (24, 32, 3), dtype=np.uint8), rng.uniform(0.5, 3, (24, 32)).astype(np.float32))
        for _ in range(3)
    ]
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        kinds = {"/cam/rgb": "sensor_msgs/msg/Image", "/cam/depth": "sensor_msgs/msg/Image",
                 "/cam/info": "sensor_msgs/msg/CameraInfo"}  # fmt: skip
        c = {t: w.add_connection(t, m, typestore=ts) for t, m in kinds.items()}
        for i, (bgr, depth) in enumerate(frames):
            t = 1_000_000_000 + i * 33_000_000
            w.write(
                c["/cam/info"],
                t,
                ts.serialize_cdr(rm.camera_info(ts, camera_info_fields(k, t, "c")), "sensor_msgs/msg/CameraInfo"),
            )
            w.write(
                c["/cam/rgb"],
                t,
                ts.serialize_cdr(rm.image(ts, image_fields(bgr, "bgr8", t, "c")), "sensor_msgs/msg/Image"),
            )
            depth_msg = rm.image(ts, image_fields(depth, "32FC1", t + 5_000_000, "c"))
            w.write(c["/cam/depth"], t + 5_000_000, ts.serialize_cdr(depth_msg, "sensor_msgs/msg/Image"))
    return frames


def test_bags_recorded_elsewhere_bgr_and_32fc1(tmp_path):
    from bags.layout import BagTopics

    frames = write_foreign_bag(tmp_path / "other")
    back = BagDataset(
        tmp_path / "other", topics=BagTopics(color="/cam/rgb", depth="/cam/depth", camera_info="/cam/info")
    )
    assert len(back) == 3 and not back.has_labels and not back.has_ground_truth
    assert np.array_equal(back[1].rgb, frames[1][0][..., ::-1]) and np.allclose(back[1].depth, frames[1][1])


def test_run_names_the_topics_of_a_foreign_bag(tiny_scene, tmp_path, capsys):
    write_foreign_bag(tmp_path / "other")
    sets = [a for o in FAST_SLAM for a in ("--set", o)]
    common = ["--preset", "tum", "--quiet", *sets]
    assert slam_main(["run", str(tmp_path / "other"), "--out", str(tmp_path / "default"), *common]) == 1
    assert "no messages on" in capsys.readouterr().err
    topics = ["--topic", "color=/cam/rgb", "--topic", "depth=/cam/depth", "--topic", "camera_info=/cam/info"]
    assert slam_main(["run", str(tmp_path / "other"), "--out", str(tmp_path / "run"), *topics, *common]) == 0
    stamps, _ = read_tum_trajectory(tmp_path / "run" / "trajectory.txt")
    assert len(stamps) == 3
    assert slam_main(["eval", str(tmp_path / "run"), "--no-write"]) == 0  # eval reopens the bag with the topics
    assert slam_main(["run", str(tmp_path / "other"), "--out", str(tmp_path / "x"), "--topic", "rgb=/cam/rgb"]) == 1
    assert "expected KEY=/topic" in capsys.readouterr().err
    assert slam_main(["run", str(tiny_scene), "--out", str(tmp_path / "y"), "--topic", "color=/cam/rgb"]) == 1
    assert "MCAP bags only" in capsys.readouterr().err


def test_corrupt_and_truncated_bags_give_clear_errors(tiny_scene, tmp_path):
    bag = tmp_path / "bag"
    convert(open_dataset(tiny_scene), bag, compress=False)
    mcap = next(bag.glob("*.mcap"))
    data = mcap.read_bytes()
    mcap.write_bytes(data[: len(data) // 2])  # truncated in the middle of the data
    with pytest.raises(BagError, match=r"corrupt or truncated|no synchronised"):
        open_bag(bag)
    info = bag_info(bag)  # no footer: described from the complete records (none: one chunk was cut)
    assert info.truncated_at is not None and "truncated at byte" in info.format()
    mcap.write_bytes(b"garbage" * 100)
    with pytest.raises(BagError, match="corrupt or truncated"):
        open_bag(bag)
    assert bag_main(["info", str(bag)]) == 1


def test_convert_refuses_to_overwrite(tiny_scene, tmp_path, capsys):
    (tmp_path / "bag").mkdir()
    assert bag_main(["convert", str(tiny_scene), "--out", str(tmp_path / "bag")]) == 1
    assert "refusing to overwrite" in capsys.readouterr().err


def test_run_on_a_bag_gives_the_same_trajectory_as_on_the_folder(tiny_scene, tmp_path):
    """With millimetre depth in both (camera.yaml depth_scale 1000), bag and folder decode to the same
    frames, so the deterministic CPU run must give the same trajectory."""
    import cv2
    import yaml

    folder = tmp_path / "mm"
    shutil.copytree(tiny_scene, folder)
    for p in sorted((folder / "depths").glob("*.png")):
        metres = cv2.imread(str(p), cv2.IMREAD_UNCHANGED).astype(np.float64) / 6553.5
        cv2.imwrite(str(p), np.round(metres * 1000).astype(np.uint16))
    cam = yaml.safe_load((folder / "camera.yaml").read_text())
    (folder / "camera.yaml").write_text(yaml.safe_dump(cam | {"depth_scale": 1000.0}))
    bag = tmp_path / "bag"
    convert(open_dataset(folder), bag)
    sets = [a for o in FAST_SLAM for a in ("--set", o)]
    common = ["--max-frames", "6", "--preset", "synthetic", "--quiet", *sets]
    assert slam_main(["run", str(bag), "--out", str(tmp_path / "a"), *common]) == 0
    assert slam_main(["run", str(folder), "--out", str(tmp_path / "b"), *common]) == 0
    sa, pa = read_tum_trajectory(tmp_path / "a" / "trajectory.txt")
    sb, pb = read_tum_trajectory(tmp_path / "b" / "trajectory.txt")
    assert np.array_equal(sa, sb) and np.abs(pa - pb).max() < 1e-9


@pytest.mark.ros
def test_bag_player_lockstep_drives_slam_node(tiny_scene, tmp_path):
    from geometry_msgs.msg import PoseStamped

    from sgs_slam_ros.bag_player import BagPlayer
    from sgs_slam_ros.slam_node import build_slam_nodes

    from ..polling import wait_for
    from ..ros.helpers import Spinner, new_context, node_params, shut_down

    bag = tmp_path / "bag"
    convert(open_dataset(tiny_scene), bag)
    remaps = ["--ros-args", "-r", "rgb/image:=/camera/color/image_raw", "-r", "depth/image:=/camera/depth/image_raw",
              "-r", "semantic/image:=/camera/semantic/image_raw",
              "-r", "rgb/camera_info:=/camera/color/camera_info"]  # fmt: skip
    ctx = new_context()
    nodes = build_slam_nodes(context=ctx, parameter_overrides=node_params(), cli_args=remaps)
    player = BagPlayer(bag, lockstep=True, lockstep_timeout_s=60.0, context=ctx)
    poses = []
    player.create_subscription(PoseStamped, "/tracking_node/pose", poses.append, 50)
    spinner = Spinner(ctx, [*nodes, player])
    try:
        assert player.wait_for_subscribers(20.0)
        stats = player.play()
        assert stats.frames == 12 and stats.lockstep_timeouts == 0
        assert wait_for(lambda: len(poses) == 12, 10.0)
        assert nodes[1].pipeline.wait_idle(30.0)
        assert nodes[1].pipeline.stats.mapped == 12  # every frame processed, in order
        assert [stamp_to_ns(p.header.stamp) for p in poses] == sorted(stamp_to_ns(p.header.stamp) for p in poses)
    finally:
        shut_down(ctx, [*nodes, player], spinner)


def test_convert_says_what_it_left_out_and_info_agrees_with_the_metadata(tmp_path, capsys):
    root = tmp_path / "rgbd_dataset_freiburg1_desk"
    # the third colour image has no depth image within 20 ms
    write_tum(root, [1.0, 1.033, 1.066, 1.1], [1.001, 1.034, 1.2, 1.101], [(0.9, 0, 0, 0, 0, 0, 0, 1)])
    out = tmp_path / "bag"
    assert bag_main(["convert", str(root), "--out", str(out), "--downscale", "2"]) == 0
    printed = capsys.readouterr().out
    assert "wrote 3 frames" in printed
    assert "left out 1 colour images without a depth image within 20 ms" in printed
    assert bag_main(["info", str(out)]) == 0
    described = capsys.readouterr().out
    table = json.loads(bag_info(out).custom["label_table"])
    entries = table["classes"]
    assert f"table '{table['name']}', {len(entries)} class" in described, described
    assert all(f"{c['id']}:{c['name']}" in described for c in entries)
    assert open_bag(out).intrinsics.width * 2 == open_dataset(root).intrinsics.width  # --downscale 2
