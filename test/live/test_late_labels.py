"""Label images that come after their frame: matched by stamp, fused into the map, every one counted."""

import json
from dataclasses import replace

import numpy as np
import pytest
import torch

from sgs_slam_core.cli import main
from sgs_slam_core.config import load_config
from sgs_slam_core.datasets import open_dataset
from sgs_slam_core.errors import ConfigError, FrameError
from sgs_slam_core.frame import CompactFrame
from sgs_slam_core.frame_data import FrameTensors
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.labels import LabelTable
from sgs_slam_core.live import SlamPipeline
from sgs_slam_core.live.label_matcher import LabelMatcher
from sgs_slam_core.runner.label_stream import LabelStream, label_releases
from sgs_slam_core.runner.realtime import RealtimeOptions, run_realtime
from sgs_slam_core.semantics import SemanticCodec, SemanticSettings
from sgs_slam_core.slam.late_labels import label_unlabelled
from sgs_slam_core.slam.system import Slam

from ..conftest import FAST_SLAM

K = Intrinsics(fx=20.0, fy=20.0, cx=8.0, cy=6.0, width=16, height=12)
MS = 1_000_000


def view(stamp_ms: int, index: int = 0) -> CompactFrame:
    depth = np.full((K.height, K.width), 5000, np.uint16)  # 1 m
    return CompactFrame(index, stamp_ms * MS, K, np.zeros((12, 16, 3), np.uint8), depth, None, np.eye(4))


def labels(value: int = 3) -> np.ndarray:
    return np.full((K.height, K.width), value, np.int32)


def test_a_label_image_finds_the_view_of_its_stamp():
    m = LabelMatcher(keep_s=2.0)
    for t in (0, 33, 66):
        assert m.add_view(view(t)) == []
    late = m.add_labels(33 * MS, labels(), arrived_at=1.0)
    assert late is not None and late.view.stamp_ns == 33 * MS and late.arrived_at == 1.0
    assert m.add_labels(50 * MS, labels(), arrived_at=1.1) is None  # no view of that stamp (yet): held
    assert (m.counts.labels_in, m.counts.labels_matched, m.counts.labels_unmatched, m.pending) == (2, 1, 0, 1)


def test_labels_that_come_before_their_view_wait_for_it():
    m = LabelMatcher(keep_s=2.0)
    m.add_view(view(0))
    assert m.add_labels(33 * MS, labels(), arrived_at=0.5) is None
    matched = m.add_view(view(33))
    assert [x.view.stamp_ns for x in matched] == [33 * MS] and m.pending == 0
    assert m.counts.labels_matched == 1


def test_views_and_pending_labels_leave_after_keep_s_and_the_lost_labels_are_counted():
    m = LabelMatcher(keep_s=1.0)
    m.add_view(view(0))
    assert m.add_labels(500 * MS, labels(), arrived_at=0.0) is None  # its view was never mapped: held
    m.add_view(view(2000))  # 2 s later:: the view of 0 s and the label of 0.5 s are gone
    assert m.counts.labels_unmatched == 1 and m.pending == 0
    assert m.add_labels(0, labels(), arrived_at=0.0) is None  # far older than anything kept
    assert m.counts.labels_unmatched == 2
    assert m.counts.labels_in == m.counts.labels_matched + m.counts.labels_unmatched + m.pending


def test_a_matcher_that_keeps_nothing_counts_every_label_unmatched():
    m = LabelMatcher(keep_s=0.0)
    assert m.add_view(view(0)) == []
    assert m.add_labels(0, labels(), arrived_at=0.0) is None
    assert m.counts.labels_unmatched == 1


def test_a_reset_counts_the_pending_labels_unmatched():
    m = LabelMatcher(keep_s=2.0)
    m.add_view(view(0))
    m.add_labels(33 * MS, labels(), arrived_at=0.0)
    m.clear()
    assert m.counts.labels_unmatched == 1 and m.pending == 0 and m.add_labels(0, labels(), 0.0) is None


def test_a_segmenter_at_3_hz_labels_every_tenth_frame_of_a_30_hz_camera_400_ms_late():
    times = np.arange(30) / 30.0
    releases = label_releases(times, LabelStream(rate_hz=3.0, delay_ms=400.0))
    assert [i for _, i in releases] == [0, 10, 20]
    assert [t for t, _ in releases] == pytest.approx([0.4, 10 / 30 + 0.4, 20 / 30 + 0.4])
    assert [i for _, i in label_releases(times, LabelStream())] == list(range(30))  # every frame, on time


@pytest.mark.parametrize("stream", [{"rate_hz": 0.0}, {"rate_hz": -1.0}, {"delay_ms": -5.0}])
def test_a_label_stream_rejects_impossible_settings(stream):
    with pytest.raises(ConfigError):
        LabelStream(**stream)


def _gaussians(points: torch.Tensor, classes: list[int], codec: SemanticCodec) -> GaussianMap:
    n = len(points)
    return GaussianMap(
        means=points,
        log_scales=torch.zeros(n, 1),
        logit_opacities=torch.zeros(n),
        colors=torch.zeros(n, 3),
        semantics=torch.zeros(n, codec.num_channels),
        labels=torch.tensor(classes, dtype=torch.long),
        birth_frame=torch.zeros(n, dtype=torch.long),
    )


def test_unlabelled_gaussians_the_view_sees_at_their_depth_take_its_class():
    codec = SemanticCodec(SemanticSettings(), LabelTable.nyu40())
    points = torch.tensor(
        [
            [0.0, 0.0, 1.0],  # on the surface, unlabelled: takes class 3
            [0.0, 0.0, 1.5],  # behind the surface (hidden): stays unlabelled
            [0.1, 0.0, 1.0],  # on the surface but already labelled 7: keeps 7
            [5.0, 0.0, 1.0],  # outside the image: stays unlabelled
            [0.0, 0.0, -1.0],  # behind the camera
        ]
    )
    g = _gaussians(points, [0, 0, 7, 0, 0], codec)
    lab = labels(3)
    lab[:, :2] = 0  # unlabelled pixels give nothing
    data = FrameTensors.from_arrays(
        0, K, np.zeros((12, 16, 3), np.uint8), np.ones((12, 16), np.float32), lab, codec, torch.device("cpu")
    )
    out, n = label_unlabelled(g, data, torch.eye(4))
    assert n == 1
    assert out.labels.tolist() == [3, 0, 7, 0, 0]
    assert torch.allclose(out.semantics[0], codec.encode(torch.tensor(3)))
    assert torch.equal(out.semantics[1:], g.semantics[1:])


def test_unlabelled_gaussians_beside_the_surface_take_the_class_of_the_nearest_measured_point():
    codec = SemanticCodec(SemanticSettings(), LabelTable.nyu40())
    # the surface at 1 m; a pixel's footprint there is 5 cm (fx 20), the reach three of them
    points = torch.tensor(
        [
            [0.0, 0.0, 1.1],  # 10 cm behind the surface: beyond the depth test, within reach
            [0.0, 0.0, 1.3],  # 30 cm behind it: out of reach (a hidden surface), stays unlabelled
            [0.25, 0.0, 1.1],  # in front of the right half: takes its class 5
        ]
    )
    g = _gaussians(points, [0, 0, 0], codec)
    lab = labels(3)
    lab[:, 12:] = 5
    data = FrameTensors.from_arrays(
        0, K, np.zeros((12, 16, 3), np.uint8), np.ones((12, 16), np.float32), lab, codec, torch.device("cpu")
    )
    out, n = label_unlabelled(g, data, torch.eye(4))
    assert n == 2
    assert out.labels.tolist() == [3, 0, 5]
    assert torch.allclose(out.semantics[2], codec.encode(torch.tensor(5)))
    assert torch.equal(out.semantics[1], g.semantics[1])


def test_label_fusion_makes_its_tensors_on_the_maps_device():
    codec = SemanticCodec(SemanticSettings(), LabelTable.nyu40())
    points = torch.tensor([[0.0, 0.0, 1.0]])
    g = _gaussians(points, [0], codec)
    data = FrameTensors.from_arrays(
        0, K, np.zeros((12, 16, 3), np.uint8), np.ones((12, 16), np.float32), labels(3), codec, torch.device("cpu")
    )
    torch.set_default_device("meta")
    try:
        out, n = label_unlabelled(g, data, torch.eye(4, device="cpu"))
    finally:
        torch.set_default_device("cpu")
    assert n == 1 and out.labels.device.type == "cpu"


def test_a_replay_with_a_segmenters_stream_fuses_its_labels_and_counts_each(tiny_scene):
    dataset = open_dataset(tiny_scene)
    slam = Slam(load_config("synthetic", overrides=list(FAST_SLAM)).for_live(), dataset.label_table)
    stream = LabelStream(rate_hz=5.0, delay_ms=150.0)  # every fourth frame of a 20 Hz camera, 150 ms late
    result = run_realtime(slam, dataset, RealtimeOptions(hz=20.0, labels=stream))
    st = result.stats
    assert st.labels_in == 3  # frames 0, 4 and 8
    assert st.labels_fused + st.labels_unmatched == st.labels_in and st.labels_fused >= 1
    assert st.label_latency_ms is not None and st.label_latency_ms >= 150.0
    assert len(slam.gaussians) and int((slam.gaussians.labels > 0).sum()) > 0  # the map knows classes
    assert slam.keyframes.find(0).labels is not None  # the first frame is a keyframe: it keeps its late labels


def test_the_first_frames_gaussians_take_their_classes_when_its_labels_come(tiny_scene):
    dataset = open_dataset(tiny_scene)
    slam = Slam(load_config("synthetic", overrides=list(FAST_SLAM)), dataset.label_table)
    frame = dataset[0]
    unlabelled = replace(frame, labels=None)
    slam.process(unlabelled)
    assert int((slam.gaussians.labels > 0).sum()) == 0
    view = slam.keyframes.find(0)
    outcome = slam.fuse_labels(view, frame.labels)
    assert outcome.keyframe and slam.keyframes.find(0).labels is not None
    labelled = slam.gaussians.labels > 0
    assert labelled.float().mean() > 0.9  # densified from this view: nearly all take a class
    assert set(slam.gaussians.labels[labelled].tolist()) <= set(np.unique(frame.labels).tolist())


def test_labels_of_the_wrong_size_are_a_frame_error_and_the_map_is_kept(tiny_scene):
    dataset = open_dataset(tiny_scene)
    slam = Slam(load_config("synthetic", overrides=list(FAST_SLAM)), dataset.label_table)
    slam.process(replace(dataset[0], labels=None))
    before = slam.gaussians
    with pytest.raises(FrameError):
        slam.fuse_labels(slam.keyframes.find(0), np.zeros((3, 3), np.int32))
    assert slam.gaussians is before


def test_a_pipeline_without_late_labels_counts_them_unmatched(tiny_scene):
    dataset = open_dataset(tiny_scene)
    slam = Slam(load_config("synthetic", overrides=[*FAST_SLAM, "device=cpu"]), dataset.label_table)
    pipeline = SlamPipeline(slam, lockstep=True, log=lambda _: None)
    try:
        pipeline.submit_labels(dataset[0].stamp_ns, dataset[0].labels)
        assert pipeline.stats.labels.labels_in == 1 and pipeline.stats.labels.labels_unmatched == 1
    finally:
        pipeline.shutdown()


def test_cli_takes_a_label_rate_and_delay_only_with_realtime(tiny_scene, tmp_path, capsys):
    out = tmp_path / "rt"
    assert main(["run", str(tiny_scene), "--out", str(out), "--label-rate-hz", "3"]) == 1
    assert "need --realtime" in capsys.readouterr().err
    sets = [a for o in FAST_SLAM for a in ("--set", o)]
    args = ["run", str(tiny_scene), "--out", str(out), "--realtime", "20", "--label-rate-hz", "5", "--quiet", *sets]
    assert main(args) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["labels_in"] == 3 and metrics["labels_fused"] + metrics["labels_unmatched"] == 3


def test_labels_rarer_than_keyframes_add_their_views_as_keyframes_and_labels_on_every_frame_add_none(tiny_scene):
    dataset = open_dataset(tiny_scene)
    slam = Slam(load_config("synthetic", overrides=[*FAST_SLAM, "mapping.iterations=2"]), dataset.label_table)
    frames = [dataset[i] for i in range(7)]
    for f in frames:
        slam.process(replace(f, labels=None))
    before = [kf.index for kf in slam.keyframes]  # keyframes.every = 5: frames 0 and 4
    for i, (_, _, c2w) in enumerate(slam.trajectory):
        view = CompactFrame.from_frame(replace(frames[i], labels=None, index=i), np.linalg.inv(c2w))
        slam.fuse_labels(view, frames[i].labels)
    assert [kf.index for kf in slam.keyframes] == before  # every frame labelled: the keyframes stay as they were
    assert all(kf.labels is not None for kf in slam.keyframes)
    slam.keyframes = type(slam.keyframes)(slam.config.keyframes)  # none held: a labelled view becomes one
    view = CompactFrame.from_frame(replace(frames[6], labels=None, index=6), np.linalg.inv(slam.trajectory[6][2]))
    assert slam.fuse_labels(view, frames[6].labels).keyframe and [kf.index for kf in slam.keyframes] == [6]
