"""slam_node with ``render.compile``: its graphs are traced on the first frame, which is left out."""

import pytest

from ..polling import wait_for
from .helpers import FAST, node_params, tiny_frames, watched_slam

pytestmark = pytest.mark.ros


def test_the_first_frame_is_traced_on_and_the_next_ones_tracked(tiny_scene):
    frames = tiny_frames(tiny_scene)[:4]
    watched = watched_slam(node_params(overrides=[*FAST, "render.backend=torch", "render.compile=true"]))
    try:
        feeder = watched.feeder
        assert wait_for(feeder.connected, 10.0), "slam_node did not subscribe"
        for frame in frames:
            feeder.publish(frame)
        # the frames after the first queue (reliable, keep all) while it is traced on: seconds, more when cold
        assert wait_for(lambda: frames[-1].stamp_ns in feeder.poses, 300.0), "no pose for the last frame"
        assert sorted(feeder.poses) == [f.stamp_ns for f in frames[1:]]
        assert any("render.compile: compiling for 64x48" in log.msg for log in watched.logs)
    finally:
        watched.shut_down()
