"""The Slam facade on the tiny synthetic scene: accuracy bounds, switches, failure handling."""

import dataclasses
import gc
import weakref

import numpy as np
import pytest
import torch

from sgs_slam_core.config import load_config
from sgs_slam_core.datasets import open_dataset
from sgs_slam_core.errors import FrameError
from sgs_slam_core.frame import Frame
from sgs_slam_core.metrics import ConfusionMatrix, ate
from sgs_slam_core.slam.motion import Start
from sgs_slam_core.slam.pose import predict_constant_velocity
from sgs_slam_core.slam.system import Slam

from ..conftest import FAST_SLAM


def run(dataset, overrides=(), frames=None):
    slam = Slam(load_config("synthetic", overrides=[*FAST_SLAM, *overrides]), dataset.label_table)
    steps = [slam.process(dataset[i]) for i in range(frames or len(dataset))]
    return slam, steps


@pytest.fixture(scope="module")
def tiny(tiny_scene):
    return open_dataset(tiny_scene)


@pytest.fixture(scope="module")
def baseline(tiny):
    return run(tiny)


def test_pose_error_and_semantics_on_the_tiny_scene(tiny, baseline):
    slam, steps = baseline
    gt = np.stack([tiny[i].gt_c2w for i in range(len(tiny))])
    est = np.stack([s.c2w for s in steps])
    assert ate(est, gt).rmse < 0.015  # 1.5 cm at 64x48 with CI-sized iteration budgets
    assert not any(s.track.failed for s in steps)
    cm = ConfusionMatrix()
    for i in (0, 5, 11):
        out = slam.render_view(steps[i].c2w)
        cm.update(slam.decode(out.semantic), tiny[i].labels)
    assert cm.miou() > 0.8
    assert set(slam.gaussians.labels.unique().tolist()) <= set(slam.label_candidates())
    assert [s.map.keyframe for s in steps] == [i == 0 or (i + 1) % 5 == 0 for i in range(12)]
    assert len(slam.keyframes) == 3 and slam.keyframes[0].rgb.dtype == np.uint8


def test_runs_are_deterministic(tiny, baseline):
    _, steps = baseline
    _, again = run(tiny, frames=4)
    for a, b in zip(steps[:4], again, strict=False):
        assert np.array_equal(a.c2w, b.c2w)


def test_semantic_switch_freezes_the_semantic_channels(tiny):
    slam, _ = run(tiny, ["tracking.weight_semantic=0", "mapping.weight_semantic=0"], frames=3)
    first = slam.gaussians.birth_frame == 0
    init = slam.codec.encode(slam.gaussians.labels[first])  # frame-0 Gaussians keep their initial targets
    assert torch.equal(slam.gaussians.semantics[first], init)
    baseline_slam, _ = run(tiny, frames=3)
    changed = baseline_slam.gaussians.semantics[baseline_slam.gaussians.birth_frame == 0]
    assert not torch.equal(
        changed, baseline_slam.codec.encode(baseline_slam.gaussians.labels[baseline_slam.gaussians.birth_frame == 0])
    )


def test_keyframe_switches_reach_the_window(tiny):
    _, on = run(tiny, ["keyframes.every=1", "keyframes.semantic_threshold=0.5"], frames=5)
    _, off = run(
        tiny,
        ["keyframes.every=1", "keyframes.semantic_filter=false", "keyframes.uncertainty_weighting=false"],
        frames=5,
    )
    w_on, w_off = on[4].map.window, off[4].map.window
    assert w_on.after_semantic < w_on.after_geometric  # near-identical views are dropped
    assert w_off.after_semantic == w_off.after_geometric
    assert len(set(w_off.weights)) == 1 and len(set(w_on.weights)) > 1  # U(t) only when switched on
    assert w_on.weights[-1] < w_on.weights[0]  # later frames weigh less


def test_a_run_keeps_one_map_version(tiny):
    """Per-frame results hold what mapping did, not the map it made (a version per frame is GBs)."""
    slam = Slam(load_config("synthetic", overrides=FAST_SLAM), tiny.label_table)
    steps = [slam.process(tiny[i]) for i in range(3)]
    old = weakref.ref(slam.gaussians.means)
    steps += [slam.process(tiny[i]) for i in range(3, 5)]
    gc.collect()
    assert all(s.map.stats is not None for s in steps)
    assert old() is None, "an old map version is still referenced"


def test_frames_without_labels_still_work(tiny):
    slam = Slam(load_config("synthetic", overrides=FAST_SLAM), tiny.label_table)
    slam.process(tiny[0])
    f = tiny[1]
    step = slam.process(dataclasses.replace(f, labels=None))
    assert not step.track.failed and step.map.stats is not None
    assert np.linalg.norm(step.c2w[:3, 3] - (np.linalg.inv(tiny[0].gt_c2w) @ f.gt_c2w)[:3, 3]) < 0.05


def test_bad_frames_raise_clear_errors(tiny):
    slam = Slam(load_config("synthetic", overrides=FAST_SLAM), tiny.label_table)
    f0 = tiny[0]
    with pytest.raises(FrameError, match="no valid depth"):
        slam.process(dataclasses.replace(f0, depth=np.zeros_like(f0.depth)))
    slam.process(f0)
    small = tiny.intrinsics.scaled(0.5)
    with pytest.raises(FrameError, match="intrinsics"):
        slam.process(Frame(f0.rgb[::2, ::2].copy(), f0.depth[::2, ::2].copy(), small))
    with pytest.raises(FrameError, match="backwards"):
        slam.process(dataclasses.replace(tiny[1], stamp_ns=-1))


def test_tracking_failure_is_flagged_and_the_map_kept(tiny):
    overrides = [*FAST_SLAM, "guard.warmup_frames=1", "motion.icp_iterations=[0]"]  # the prior alone
    slam = Slam(load_config("synthetic", overrides=overrides), tiny.label_table)
    for i in range(4):
        slam.process(tiny[i])
    before = slam.gaussians.state_dict()
    f = tiny[4]
    rng = np.random.default_rng(0)
    garbage = dataclasses.replace(f, depth=(f.depth * rng.uniform(0.3, 3.0, f.depth.shape)).astype(np.float32))
    step = slam.process(garbage)
    assert step.track.failed and step.map.stats is None and step.track.failure_reason
    after = slam.gaussians.state_dict()
    assert all(torch.equal(before[k], after[k]) for k in before)
    assert slam.failures == 1
    # The motion prior continues from the accepted poses, not from where the failed one ended.
    accepted = slam.trajectory[-3][2], slam.trajectory[-2][2]
    data = slam._frame_tensors(tiny[5], 5)
    start = slam.motion.predict(tiny[5].stamp_ns, data)
    expected = predict_constant_velocity(accepted[1], accepted[0], 2.0)  # two frame intervals on
    assert np.allclose(start, expected, atol=1e-6)
    good = slam.process(tiny[5])
    assert not good.track.failed


@pytest.mark.parametrize("retry", [True, False])
@pytest.mark.parametrize("features", [True, False])
def test_a_failed_frame_is_tracked_again_from_the_features_or_the_last_accepted_pose(tiny, retry, features):
    """The second start is the features' pose where they have one, else the last accepted pose."""
    adam = "tracking.method=adam"  # its iterations count both attempts
    overrides = [*FAST_SLAM, adam, "guard.warmup_frames=1", f"guard.retry={str(retry).lower()}"]
    overrides += [f"features.enabled={str(features).lower()}", "guard.lost_after=0"]
    slam = Slam(load_config("synthetic", overrides=overrides), tiny.label_table)
    for i in range(4):
        slam.process(tiny[i])
    off = np.eye(4)
    off[:3, 3] = [0.6, 0.0, 0.0]  # a start far off, as after a reversal the motion prior is
    start = slam.motion.start
    slam.motion.start = lambda stamp, data, view=None: Start(start(stamp, data, None).c2w @ off, False)
    step = slam.process(tiny[4])
    assert step.track.failed is not retry
    gt = np.linalg.inv(tiny[0].gt_c2w) @ tiny[4].gt_c2w
    if retry:
        assert np.linalg.norm(step.c2w[:3, 3] - gt[:3, 3]) < 0.05
        assert step.track.result.iterations > slam.config.tracking.adam.iterations  # both attempts counted
    assert slam.failures == int(not retry)


def test_gt_pose_mode(tiny):
    _, steps = run(tiny, ["tracking.use_gt_pose=true"], frames=3)
    gt = np.linalg.inv(tiny[0].gt_c2w) @ tiny[2].gt_c2w
    assert np.allclose(steps[2].c2w, gt) and steps[2].track.result is None


def test_classes_may_be_re_decoded_after_keyframes_only(tiny, monkeypatch):
    """Live runs re-decode after keyframes (frames 0 and 4 of six); the Gaussians a frame adds carry its labels."""
    calls = []
    refreshed = Slam._refreshed_labels

    def spy(self, gaussians):
        calls.append(self.frames_processed)
        return refreshed(self, gaussians)

    monkeypatch.setattr(Slam, "_refreshed_labels", spy)
    counts = []
    for only in ("false", "true"):
        calls.clear()
        slam, steps = run(tiny, [f"mapping.refresh_labels_keyframes_only={only}"], frames=6)
        counts.append(len(calls))
        assert [s.map.keyframe for s in steps] == [True, False, False, False, True, False]
        assert set(slam.gaussians.labels.unique().tolist()) <= slam.seen_ids
        slam.refresh_labels()  # a run's end: once where frames were mapped since the last re-decoding
        slam.refresh_labels()
        counts.append(len(calls))
    assert counts == [6, 6, 2, 3]
