"""segmentation_node's rate cap, with a stand-in model (runs without the optional transformers extra)."""

import time

import numpy as np
import pytest
from rclpy.parameter import Parameter
from sensor_msgs.msg import Image

from sgs_slam_ros.segmentation_node import SegmentationNode

from ..polling import wait_for
from .helpers import Feeder, Spinner, new_context, shut_down, tiny_frames

pytestmark = pytest.mark.ros


class CountingModel:
    """A segmenter that answers at once with one class: what the node does with it is under test."""

    name, device = "counting", "cpu"

    def __init__(self) -> None:
        self.calls: list[float] = []  # time.monotonic() of each call

    def __call__(self, rgb: np.ndarray, downscale: float = 1.0) -> np.ndarray:  # [H, W, 3] -> [H, W] uint16
        self.calls.append(time.monotonic())
        return np.full(rgb.shape[:2], 5, dtype=np.uint16)


@pytest.mark.parametrize("max_rate_hz", [0.0, 4.0])
def test_a_rate_cap_spaces_the_model_runs_by_its_period(max_rate_hz, tiny_scene):
    frame = tiny_frames(tiny_scene)[0]
    ctx = new_context()
    model = CountingModel()
    seg = SegmentationNode(
        segmenter=model, context=ctx, parameter_overrides=[Parameter("max_rate_hz", value=max_rate_hz)]
    )
    feeder = Feeder(ctx)
    labels: list[Image] = []
    feeder.create_subscription(Image, "/semantic/image", labels.append, 100)
    spinner = Spinner(ctx, [seg, feeder])
    try:
        assert wait_for(lambda: feeder.pubs["/rgb/image"].get_subscription_count() >= 1, 10.0)
        sent = 0
        start = time.monotonic()
        while time.monotonic() - start < 1.5:  # a 40 Hz camera for 1.5 s
            feeder.publish(frame, semantic=False)
            sent += 1
            time.sleep(0.025)  # the camera's pace
        assert wait_for(lambda: seg.frames_in == sent and seg.segmented + seg.dropped == sent, 10.0)
        gaps = np.diff(model.calls)
        if max_rate_hz:
            assert len(model.calls) >= 3 and (gaps >= 1.0 / max_rate_hz - 0.01).all(), gaps
        else:
            assert len(model.calls) >= sent // 2  # an instant model keeps up with the camera
        assert wait_for(lambda: len(labels) == seg.segmented, 5.0)
    finally:
        shut_down(ctx, [seg, feeder], spinner)
