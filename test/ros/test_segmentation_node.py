"""segmentation_node with the real SegFormer class (random weights: nothing is downloaded) into slam_node."""

import json

import numpy as np
import pytest

pytest.importorskip("transformers", reason="the optional extra sgs_slam_ros[segmentation] is not installed")

from sensor_msgs.msg import Image, PointCloud2
from std_msgs.msg import String

from msg_adapters import labels_from_image, pointcloud_to_numpy, stamp_to_ns
from sgs_slam_core.labels import LabelTable
from sgs_slam_core.segmentation import SegmentationError, Segmenter
from sgs_slam_ros.qos import latched_qos
from sgs_slam_ros.segmentation_node import SegmentationNode
from sgs_slam_ros.slam_node import build_slam_nodes

from ..polling import wait_for
from .helpers import Feeder, Spinner, new_context, node_params, shut_down, tiny_frames

pytestmark = pytest.mark.ros


@pytest.fixture(scope="module")
def segmenter():
    return Segmenter.random(seed=0)


def test_segmenter_maps_the_models_classes_to_nyu40(segmenter):
    rgb = np.random.default_rng(0).integers(0, 255, (48, 64, 3), dtype=np.uint8)
    ids = segmenter(rgb)
    assert ids.shape == (48, 64) and ids.dtype == np.uint16
    ade = segmenter.ade20k_classes(rgb).numpy()
    assert np.array_equal(ids, segmenter.lut.numpy()[ade])  # every pixel through the documented table
    with pytest.raises(SegmentationError, match="HxWx3 uint8"):
        segmenter(rgb[..., 0])


def test_a_smaller_model_input_gives_labels_at_the_image_size(segmenter):
    rgb = np.random.default_rng(1).integers(0, 255, (96, 128, 3), dtype=np.uint8)
    full, half = segmenter(rgb), segmenter(rgb, downscale=2.0)
    assert half.shape == full.shape == (96, 128) and half.dtype == np.uint16
    assert not np.array_equal(segmenter.ade20k_classes(rgb, 2.0), segmenter.ade20k_classes(rgb))  # it saw less
    # the model's input keeps 32 px a side: 96 / 16 would be 6, so 16 acts as 3
    assert np.array_equal(segmenter.ade20k_classes(rgb, 16.0), segmenter.ade20k_classes(rgb, 3.0))
    with pytest.raises(SegmentationError, match="downscale"):
        segmenter(rgb, downscale=0.5)
    with pytest.raises(SegmentationError, match="too small"):
        segmenter(rgb[:20])


def test_unavailable_weights_are_one_clear_line(monkeypatch, tmp_path):
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    with pytest.raises(SegmentationError) as err:
        Segmenter.from_pretrained(str(tmp_path / "no_such_model"))
    assert "cannot load the segmentation model" in str(err.value) and "\n" not in str(err.value)


def counts(seg: SegmentationNode, *keys: str) -> dict[str, str] | list[str]:
    """The segmenter's /diagnostics values now (``keys``: just those, in order)."""
    seg.diagnostics.publish()
    values = {kv.key: kv.value for kv in seg.diagnostics.last_status.values}
    return [values[k] for k in keys] if keys else values


def labelled(view: Image, by_stamp: dict[int, np.ndarray]) -> bool:
    """Most of a render is classes, and its frame's label image came (a busy model drops some)."""
    return (labels_from_image(view) > 0).mean() > 0.5 and stamp_to_ns(view.header.stamp) in by_stamp


def test_labels_carry_the_input_stamp_and_frame_and_reach_the_map_and_its_renders(segmenter, tiny_scene):
    frames = tiny_frames(tiny_scene)
    ctx = new_context()
    seg = SegmentationNode(segmenter=segmenter, context=ctx)
    nodes = build_slam_nodes(context=ctx, parameter_overrides=node_params(points_rate_hz=10.0, render_rate_hz=30.0))
    feeder = Feeder(ctx)
    labels, tables, points, rendered = [], [], [], []
    feeder.create_subscription(Image, "/semantic/image", labels.append, 50)
    feeder.create_subscription(Image, "/mapping_node/render/labels", rendered.append, 50)
    feeder.create_subscription(String, "/semantic/label_table", tables.append, latched_qos())
    feeder.create_subscription(PointCloud2, "/mapping_node/points", points.append, latched_qos())
    spinner = Spinner(ctx, [seg, *nodes, feeder])
    try:
        assert wait_for(lambda: feeder.connected(subscribers=1) and tables, 10.0)
        assert LabelTable.from_dict(json.loads(tables[-1].data)) == LabelTable.nyu40()
        for frame in frames[:3]:  # colour, depth and camera_info only: the labels come from the model
            feeder.publish(frame, semantic=False)
            assert wait_for(lambda f=frame: f.stamp_ns in feeder.poses, 60.0)
        # tracking never waits for labels: wait until each image was segmented (and its labels came) or dropped
        assert wait_for(lambda: seg.segmented + seg.dropped == 3 and len(labels) == seg.segmented, 20.0)
        first = labels[0]
        assert (
            stamp_to_ns(first.header.stamp) == frames[0].stamp_ns
            and first.header.frame_id == "camera_color_optical_frame"
        )
        assert first.encoding == "16UC1" and (first.width, first.height) == (64, 48)
        published = {int(i) for m in labels for i in np.unique(labels_from_image(m))}
        expected = segmenter(frames[0].rgb)
        assert np.array_equal(labels_from_image(first), expected)

        def map_classes() -> set[int]:
            return set(np.unique(pointcloud_to_numpy(points[-1])["label"]).tolist()) - {0} if points else set()

        # the labels come after their frames and are fused when they come: the map and its renders follow
        assert wait_for(map_classes, 20.0)
        in_map = map_classes()
        assert in_map <= published, (in_map, published)  # the map's classes are the model's
        by_stamp = {stamp_to_ns(m.header.stamp): labels_from_image(m) for m in labels}
        assert wait_for(lambda: rendered and labelled(rendered[-1], by_stamp), 20.0)
        view = rendered[-1]
        model = by_stamp[stamp_to_ns(view.header.stamp)]
        drawn = labels_from_image(view)
        seen = drawn > 0
        assert seen.mean() > 0.5 and set(np.unique(drawn[seen]).tolist()) <= published
        # the rendered classes are the model's labels of that frame, pixel by pixel, far above chance (the
        # agreement of two unrelated images with these class frequencies); random weights give noisy labels
        agree = (drawn[seen] == model[seen]).mean()
        classes = np.union1d(drawn[seen], model[seen])
        chance = sum((drawn[seen] == c).mean() * (model[seen] == c).mean() for c in classes)
        assert agree > 1.5 * chance, (agree, chance)

        # a busy model drops the older of two waiting images: each of the 3 is segmented or dropped
        assert wait_for(lambda: sum(int(v) for v in counts(seg, "frames_segmented", "frames_dropped")) == 3, 10.0)
        values = counts(seg)
        assert values["frames_in"] == "3" and int(values["frames_segmented"]) >= 2
        assert values["label_table"].startswith("nyu40")
    finally:
        shut_down(ctx, [seg, *nodes, feeder], spinner)
