"""bag_player and slam_node on two hosts (network namespaces, each with its own /dev/shm): frames cross as UDP."""

from __future__ import annotations

import pytest

from bags import convert
from bench.two_hosts import REMAPS, TwoHosts, play_across, unavailable
from sgs_slam_core.datasets import open_dataset

pytestmark = pytest.mark.ros


@pytest.fixture
def tiny_bag(tiny_scene, tmp_path):
    """The tiny scene as an uncompressed bag, where two hosts can be made (skipped with the reason otherwise)."""
    why = unavailable()
    if why is not None:
        pytest.skip(f"two hosts on one machine: {why}")
    bag = tmp_path / "bag"
    convert(open_dataset(tiny_scene), bag, compress=False)
    return bag


def test_every_frame_crosses_to_the_other_host_with_the_shipped_settings(tiny_bag):
    with TwoHosts() as hosts:
        counts = play_across(hosts, tiny_bag, ["preset:=synthetic", "use_semantics:=false"], REMAPS, timeout_s=180.0)
    assert counts["sent"] == 12
    assert counts["frames_in"] == 12 and counts["frames_lost"] == 0, counts  # none lost between the hosts
    assert counts["frames_tracked"] + counts["frames_dropped"] + counts["frames_rejected"] == 12, counts


def test_the_tracker_forwards_its_frames_to_a_mapper_on_the_other_host(tiny_bag):
    params = ["preset:=synthetic", "use_semantics:=false", "downscale:=2.0"]
    with TwoHosts() as hosts:
        counts = play_across(hosts, tiny_bag, params, REMAPS, timeout_s=180.0, split=True)
    assert counts["sent"] == 12 and counts["frames_in"] == 12, counts  # camera -> tracker, on host a
    forwarded = counts["frames_forwarded"]
    assert forwarded >= 2, counts  # the first frame, and frames tracked against the map that came back
    assert counts["mapper_frames_in"] == forwarded and counts["mapper_frames_mapped"] >= 1, counts
