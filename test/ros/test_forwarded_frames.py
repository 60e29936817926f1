"""tracking_node forwards the frames it accepts at the processing size; mapping_node maps those, not the camera's."""

from __future__ import annotations

import time

import pytest
from rclpy.parameter import Parameter

from sgs_slam_core.slam.system import Slam
from sgs_slam_ros.mapping_node import MappingNode
from sgs_slam_ros.tracking_node import TrackingNode

from ..polling import wait_for
from .helpers import FAST, Feeder, Spinner, new_context, node_params, shut_down, tiny_frames

pytestmark = pytest.mark.ros


def test_the_mapper_maps_the_frames_the_tracker_forwards(tiny_scene):
    frames = tiny_frames(tiny_scene)[:4]
    ctx = new_context()
    common = {"downscale": 2.0, "gaussians_rate_hz": 0.0}
    tracker = TrackingNode(
        standalone=True,
        context=ctx,
        parameter_overrides=node_params(**common, map_source="topic", forward_frames=True),
    )
    mapper = MappingNode(
        context=ctx, parameter_overrides=node_params(**common, pose_source="topic", frame_source="tracking_node")
    )
    feeder = Feeder(ctx)
    spinner = Spinner(ctx, [tracker, mapper, feeder])
    try:
        # only the tracker reads the camera; the mapper reads what the tracker forwards
        assert wait_for(lambda: feeder.connected(subscribers=1), 30.0)
        assert feeder.pubs["/rgb/image"].get_subscription_count() == 1
        assert wait_for(lambda: tracker.forwarder._rgb.get_subscription_count() == 1, 30.0)
        for f in frames:
            feeder.publish(f)
            assert wait_for(lambda f=f: f.stamp_ns in feeder.poses, 60.0), f"no pose for frame {f.index}"
        assert wait_for(lambda: mapper.pipeline.stats.mapped == len(frames), 60.0)
        assert wait_for(lambda: mapper.pipeline.stats.labels.labels_in == len(frames), 30.0)
    finally:
        shut_down(ctx, [tracker, mapper, feeder], spinner)
    sent = tracker.forwarder.counts()
    assert sent["frames_forwarded"] == str(len(frames)) and sent["labels_forwarded"] == str(len(frames))
    a = mapper.camera.assembler
    k = frames[0].intrinsics
    # forwarded at the tracker's processing size, and not shrunk again by the mapper
    assert a.input_size == a.processing_size == (k.width // 2, k.height // 2)
    assert a.colour_in == len(frames) and a.frames_rejected == 0
    # the mapper's map frame is the tracker's: the forwarded frames are mapped at the poses it published
    mapped = {stamp: c2w for _, stamp, c2w in mapper.pipeline.slam.trajectory}
    assert sorted(mapped) == sorted(feeder.poses)


def test_forward_frames_is_read_only_and_off_by_default(tiny_scene):
    ctx = new_context()
    tracker = TrackingNode(standalone=True, context=ctx, parameter_overrides=node_params(map_source="topic"))
    try:
        assert tracker.forwarder is None
        result = tracker.set_parameters([Parameter("forward_frames", value=True)])[0]
        assert not result.successful
    finally:
        shut_down(ctx, [tracker])


def test_a_mapper_that_compiles_traces_its_graphs_on_the_first_frame_and_maps_it_too(tiny_scene, monkeypatch):
    frames = tiny_frames(tiny_scene)[:3]
    traced = []
    prepare = Slam.prepare

    def spy(slam, announce, sample=None):
        prepare(slam, announce, sample)
        if sample is not None:
            traced.append(sample.stamp_ns)

    monkeypatch.setattr(Slam, "prepare", spy)
    ctx = new_context()
    tracker = TrackingNode(
        standalone=True,
        context=ctx,
        parameter_overrides=node_params(map_source="topic", forward_frames=True),
    )
    compiled = [*FAST, "render.backend=torch", "render.compile=true"]
    mapper = MappingNode(
        context=ctx,
        parameter_overrides=node_params(overrides=compiled, pose_source="topic", frame_source="tracking_node"),
    )
    feeder = Feeder(ctx)
    spinner = Spinner(ctx, [tracker, mapper, feeder])
    try:
        assert wait_for(lambda: feeder.connected(subscribers=1), 30.0)
        assert wait_for(lambda: tracker.forwarder._rgb.get_subscription_count() == 1, 30.0)
        for f in frames:
            feeder.publish(f)
            assert wait_for(lambda f=f: f.stamp_ns in feeder.poses, 60.0), f"no pose for frame {f.index}"
        # the first frame waits while the graphs are traced (seconds, more with a cold cache), then is mapped
        assert wait_for(lambda: mapper.pipeline.stats.mapped == len(frames), 300.0)
        # the tracker sent the last frame and its pose again each second while it waited: mapped once
        time.sleep(1.5)
    finally:
        shut_down(ctx, [tracker, mapper, feeder], spinner)
    assert traced == [frames[0].stamp_ns]
    assert [stamp for _, stamp, _ in mapper.pipeline.slam.trajectory] == [f.stamp_ns for f in frames]
