"""Unit tests of SLAM building blocks."""

import dataclasses

import numpy as np
import pytest
import torch

from sgs_slam_core.config import load_config
from sgs_slam_core.config.sections import GuardSettings, KeyframeSettings, MappingSettings
from sgs_slam_core.frame import CompactFrame, Frame
from sgs_slam_core.frame_data import FrameTensors
from sgs_slam_core.geometry import Intrinsics, se3_exp
from sgs_slam_core.kernels import build_kernels
from sgs_slam_core.labels import LabelTable
from sgs_slam_core.render import RenderSettings
from sgs_slam_core.semantics import SemanticCodec, SemanticSettings
from sgs_slam_core.slam.edits import EditLocks
from sgs_slam_core.slam.guard import TrackingGuard
from sgs_slam_core.slam.keyframe_store import KeyframeStore
from sgs_slam_core.slam.keyframes import (
    Window,
    is_keyframe,
    label_miou,
    label_miou_per_class,
    overlap_scores,
    select_window,
)
from sgs_slam_core.slam.optimizer import GaussianOptimizer
from sgs_slam_core.slam.pose import PoseParameters, predict_constant_velocity
from sgs_slam_core.slam.window import upload_window

from ..render.scenes import random_scene

K = Intrinsics(50.0, 50.0, 31.5, 23.5, 64, 48)


def keyframe(index, w2c, labels):
    return CompactFrame(index, index, K, np.zeros((48, 64, 3), np.uint8), np.zeros((48, 64), np.uint16), labels, w2c)


def test_constant_velocity_repeats_the_last_motion():
    a = np.eye(4)
    b = se3_exp(torch.tensor([0.1, 0.0, 0.0, 0.0, 0.05, 0.0], dtype=torch.float64)).numpy()
    pred = predict_constant_velocity(b, a)
    assert np.allclose(np.linalg.inv(b) @ pred, b, atol=1e-12)
    assert np.array_equal(predict_constant_velocity(b, None), b)


def test_constant_velocity_scales_the_motion_by_the_time_gap():
    """A frame two gaps later (one dropped in live mode) moves twice as far and turns twice as much."""
    a = np.eye(4)
    b = se3_exp(torch.tensor([0.1, 0.0, 0.02, 0.0, 0.05, 0.0], dtype=torch.float64)).numpy()
    twice = predict_constant_velocity(b, a, 2.0)
    step = np.linalg.inv(b) @ twice  # the predicted motion from b
    assert np.allclose(step[:3, 3], 2 * b[:3, 3], atol=1e-12)
    assert np.allclose(step[:3, :3], b[:3, :3] @ b[:3, :3], atol=1e-12)
    assert np.array_equal(predict_constant_velocity(b, a, 1.0), predict_constant_velocity(b, a))


def test_keyframes_with_skipped_frames_take_the_first_past_each_boundary():
    every = 5
    lockstep, last = [], None
    for i in range(20):  # every frame offered: the reference's rule (0, 4, 9, 14, 19)
        if is_keyframe(i, every, last):
            lockstep.append(i)
            last = i
    assert lockstep == [i for i in range(20) if i == 0 or (i + 1) % every == 0]
    live, last = [], None
    for i in (0, 3, 7, 8, 13, 16, 21):  # live mapping skips frames
        if is_keyframe(i, every, last):
            live.append(i)
            last = i
    assert live == [0, 7, 13, 16, 21]


def test_pose_parameters_start_at_the_given_pose_and_move_in_the_camera_frame():
    w2c = se3_exp(torch.tensor([0.3, -0.2, 1.0, 0.1, 0.2, 0.3], dtype=torch.float64)).numpy()
    p = PoseParameters(w2c, torch.device("cpu"))
    assert np.allclose(p.numpy(), w2c, atol=1e-6)
    with torch.no_grad():
        p.rho += torch.tensor([0.0, 0.0, -0.5])  # moving the world by -0.5 along the camera's z ...
    c2w, c2w0 = np.linalg.inv(p.numpy()), np.linalg.inv(w2c)
    assert np.allclose(c2w[:3, 3] - c2w0[:3, 3], 0.5 * c2w0[:3, 2], atol=1e-6)  # ... moves the camera forward


def test_optimizer_prune_keeps_adam_moments_aligned():
    gm, _ = random_scene(10, 8, 8)
    opt = GaussianOptimizer(gm, MappingSettings())
    loss = sum((v * (i + 1)).sum() for i, v in enumerate(opt.params.values()))
    loss.backward()
    opt.step()
    moments = opt.adam.state["means"].exp_avg.clone()
    stepped = opt.params["means"].detach().clone()
    keep = torch.arange(10) % 3 != 0
    assert opt.prune(keep) == 4
    new = opt.params["means"]
    assert new.shape == (6, 3) and torch.equal(opt.adam.state["means"].exp_avg, moments[keep])
    assert torch.equal(new.detach(), stepped[keep]) and torch.equal(opt.result().labels, gm.labels[keep])
    assert len(opt.result()) == 6 and opt.result().labels.shape == (6,)
    before = new.detach().clone()
    new.sum().backward()
    opt.step()  # the step after a prune updates the survivors
    assert not torch.equal(opt.params["means"].detach(), before)


def test_overlap_scores_and_label_miou():
    pts = np.array([[0.0, 0.0, 2.0], [0.2, 0.0, 2.0], [0.0, 0.0, -1.0]])
    behind = np.eye(4)
    behind[2, 3] = 5.0  # a keyframe 5 m further back sees all three points
    turned = np.diag([1.0, 1.0, -1.0, 1.0])  # looking the other way: only the point behind
    scores = overlap_scores(
        pts, [keyframe(0, np.eye(4), None), keyframe(1, behind, None), keyframe(2, turned, None)], 0.0
    )
    assert scores == pytest.approx([2 / 3, 1.0, 1 / 3])
    a = np.array([[1, 1, 2], [0, 2, 2]])
    assert label_miou(a, a) == 1.0
    assert label_miou(a, np.array([[1, 2, 2], [0, 2, 2]])) == pytest.approx((1 / 2 + 3 / 4) / 2)


@pytest.mark.parametrize("top", [2, 12, 1023, 5000])
def test_label_miou_confusion_matches_the_per_class_reference(top):
    rng = np.random.default_rng(top)
    for dtype in (np.uint16, np.int32):
        a = rng.integers(0, top, (48, 64)).astype(dtype)
        b = np.where(rng.random((48, 64)) < 0.7, a, rng.integers(0, top, (48, 64))).astype(dtype)
        assert label_miou(a, b) == label_miou_per_class(a, b)
    assert label_miou(np.zeros((4, 4), np.uint16), np.zeros((4, 4), np.uint16)) == 0.0
    with pytest.raises(ValueError, match="differ in size"):
        label_miou(np.zeros((4, 4)), np.zeros((4, 5)))


def test_select_window_filters_in_order():
    labels = np.zeros((48, 64), np.int32)
    labels[:, 32:] = 3
    other = np.zeros((48, 64), np.int32)
    other[:, 10:] = 5
    store = [keyframe(i, np.eye(4), labels if i % 2 else other) for i in range(6)]
    pts = np.array([[0.0, 0.0, 2.0]] * 10)
    s = KeyframeSettings(window_size=24, semantic_threshold=0.7)
    w = select_window(store, pts, labels, 30, s, np.random.default_rng(0))
    assert (w.candidates, w.after_geometric, w.after_semantic) == (5, 5, 3)  # keyframes 1 and 3 repeat the view
    assert w.keyframes[-1] == 5 and 1 not in w.keyframes and 3 not in w.keyframes
    assert len(w.weights) == len(w.keyframes) + 1 and w.weights[-1] < w.weights[0]


def test_guard_flags_jumps_after_warmup():
    g = TrackingGuard(GuardSettings(warmup_frames=2, residual_jump=5.0))
    for _ in range(5):
        assert g.check(0.005, 1.0, 0.8) is None
    assert "depth residual" in g.check(0.2, 1.0, 0.8)
    assert "pixels" in g.check(0.005, 1.0, 0.01)
    assert g.check(0.006, 1.1, 0.8) is None


def test_compact_frames_round_trip_depth_to_a_fifth_of_a_millimetre():
    depth = np.random.default_rng(0).uniform(0.1, 8.0, (48, 64)).astype(np.float32)
    f = Frame(np.zeros((48, 64, 3), np.uint8), depth, K, np.ones((48, 64), np.int32))
    c = CompactFrame.from_frame(f, np.eye(4))
    assert np.abs(c.depth_m - depth).max() <= 1e-4 + 1e-6
    codec = SemanticCodec(load_config("synthetic").semantic, LabelTable.nyu40())
    t = FrameTensors.from_compact(c, codec, torch.device("cpu"))
    assert isinstance(t, FrameTensors) and t.semantic.shape == (48, 64, 3)


def test_the_valid_mask_follows_depth_and_ignore():
    depth = torch.tensor([[0.0, 1.0], [2.0, 3.0]])
    t = FrameTensors(0, K, torch.zeros(2, 2, 3), depth, None, None)
    assert t.valid.tolist() == [[False, True], [True, True]]
    assert t.valid is t.valid  # kept between asks
    locked = t.with_ignore(torch.tensor([[False, False], [True, False]]))  # the edit locks at the time of use
    assert locked.valid.tolist() == [[False, True], [False, True]]
    assert t.valid.tolist() == [[False, True], [True, True]]  # the frame itself is unchanged
    with pytest.raises(dataclasses.FrozenInstanceError):
        t.depth = torch.zeros(2, 2)


def test_the_first_mapping_steps_render_the_newest_window_frame(monkeypatch):
    from sgs_slam_core.slam import mapper

    gm, k = random_scene(300, 32, 24, seed=1)
    seen: list[float] = []

    kernels = build_kernels(RenderSettings(backend="torch"), "cpu")
    real_render = kernels.render

    def recording_render(gaussians, intrinsics, w2c, with_semantics):
        seen.append(float(w2c[0, 3]))  # the frame's x offset identifies it
        return real_render(gaussians, intrinsics, w2c, with_semantics=with_semantics)

    with torch.no_grad():
        out = real_render(gm, k, torch.eye(4))
    monkeypatch.setattr(kernels, "render", recording_render)
    data = FrameTensors(0, k, out.color, out.depth, None, None)
    window = []
    for x in (0.0, 0.25, 0.5):  # the last one is the newest frame (exact in float32)
        w2c = torch.eye(4)
        w2c[0, 3] = x
        window.append(mapper.WindowFrame(data, w2c, 1.0))
    s = MappingSettings(iterations=12, current_frame_steps=5, prune_iterations=())
    mapper.map_window(gm, window, s, kernels, 1.0, False, np.random.default_rng(0))
    assert seen[:5] == [0.5] * 5 and len(seen) == 12
    assert {0.0, 0.25} <= set(seen[5:])  # then uniformly over the window


def test_window_keyframes_are_decoded_when_a_mapping_step_draws_them(monkeypatch):
    store = KeyframeStore(KeyframeSettings(max_keyframes=None))
    labels = np.ones((48, 64), np.uint16)
    for i in range(3):
        store.add(keyframe(i, np.eye(4), labels if i else None))
    decoded = []
    real = FrameTensors.from_compact
    monkeypatch.setattr(
        FrameTensors,
        "from_compact",
        staticmethod(lambda kf, codec, dev: decoded.append(kf.index) or real(kf, codec, dev)),
    )
    codec = SemanticCodec(SemanticSettings(), LabelTable.nyu40())
    rgb, depth = np.zeros((48, 64, 3), np.uint8), np.ones((48, 64), np.float32)
    current = FrameTensors.from_arrays(9, K, rgb, depth, labels, codec, torch.device("cpu"))
    frames = upload_window(store, Window((0, 2), (1.0, 1.0, 1.0), 2, 2, 2), current, np.eye(4), codec, EditLocks())
    assert decoded == [] and [f.has_semantic for f in frames] == [False, True, True]
    assert frames[1].load().index == 2 and frames[1].load().semantic is not None and decoded == [2, 2]
    assert frames[2].load() is current and decoded == [2, 2]  # each draw decodes; the current frame is held
