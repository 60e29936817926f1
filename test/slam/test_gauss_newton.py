"""The Gauss-Newton tracker: analytic Jacobians against autograd, and the pose it recovers."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from sgs_slam_core.config import load_config
from sgs_slam_core.config.sections import DensifySettings, GaussNewtonSettings, TrackingSettings
from sgs_slam_core.datasets import open_dataset
from sgs_slam_core.errors import ConfigError
from sgs_slam_core.frame_data import FrameTensors
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.geometry import se3_exp
from sgs_slam_core.geometry.camera import Intrinsics, vertex_map
from sgs_slam_core.geometry.depth_noise import DepthNoise
from sgs_slam_core.geometry.icp import (
    IcpLevel,
    _associate,
    _channel_rows,
    channel_pyramid,
    icp_pyramid,
    source_channels,
)
from sgs_slam_core.kernels import build_kernels, render
from sgs_slam_core.render import RenderSettings
from sgs_slam_core.slam.densify import gaussians_from_pixels
from sgs_slam_core.slam.system import Slam
from sgs_slam_core.slam.trackers import AdamTracker, GaussNewtonTracker, build_tracker
from sgs_slam_core.slam.trackers import gauss_newton as gauss_newton_module

from ..conftest import FAST_SLAM

SETTINGS = RenderSettings(backend="torch")
TORCH = build_kernels(SETTINGS, "cpu")


def gn_tracker(gn: GaussNewtonSettings, sil_threshold: float = 0.99) -> GaussNewtonTracker:
    """The Gauss-Newton tracker on the reference kernels, its pyramid kept down to 8 px wide levels
    (``IcpSettings.min_width``): the 64x48 test frames then have three.
    """
    s = TrackingSettings(method="gauss_newton", sil_threshold=sil_threshold, gauss_newton=gn)
    tracker = GaussNewtonTracker(s, TORCH)
    tracker.icp = replace(tracker.icp, min_width=8)
    return tracker


def target_frame(width: int = 64, height: int = 48) -> tuple[GaussianMap, FrameTensors]:
    """A textured, bumpy wall made into opaque Gaussians as densification makes them, and the map
    rendered at the identity pose as the observation (depth and colour as rendered, as mapping fits them).
    """
    k = Intrinsics(0.9 * width, 0.9 * width, (width - 1) / 2, (height - 1) / 2, width, height)
    v, u = torch.meshgrid(torch.arange(2.0 * height) / 2, torch.arange(2.0 * width) / 2, indexing="ij")
    fine = Intrinsics(2 * k.fx, 2 * k.fy, 2 * k.cx + 0.5, 2 * k.cy + 0.5, 2 * width, 2 * height)
    depth = 2.5 + 0.01 * (u - k.cx) + 0.15 * torch.sin(u / 5) * torch.cos(v / 4)
    rgb = torch.stack(
        [0.5 + 0.4 * torch.sin(u / 3), 0.5 + 0.4 * torch.cos(v / 2.5), 0.5 + 0.2 * torch.sin((u + v) / 4)], dim=-1
    )
    labels = (u // 16 + v // 16).long() % 3
    surface = FrameTensors(0, fine, rgb, depth, labels, rgb.clone())
    gm = gaussians_from_pixels(surface, torch.eye(4), depth > 0, 3, DensifySettings(initial_opacity=0.95))
    with torch.no_grad():
        out = render(gm, k, torch.eye(4), SETTINGS)
    return gm, FrameTensors(
        0, k, out.color, torch.where(out.silhouette > 0.99, out.depth, 0.0), None, out.semantic.clone()
    )


def test_channel_jacobians_match_autograd_on_a_linear_image():
    """On an image linear in (u, v) central differences are exact, so the rows must equal autograd's."""
    k = Intrinsics(50.0, 55.0, 20.0, 15.0, 40, 30)
    v, u = torch.meshgrid(torch.arange(30.0), torch.arange(40.0), indexing="ij")
    image = torch.stack([0.01 * u - 0.02 * v + 0.3, 0.005 * u + 0.01 * v], dim=-1)  # [H, W, 2]
    level = icp_pyramid(torch.full((30, 40), 2.0), k, 1)[0]
    level = level.with_channels(channel_pyramid(image, torch.ones(30, 40, dtype=torch.bool), 1)[0])
    gen = torch.Generator().manual_seed(0)
    pu, pv = torch.rand(50, generator=gen) * 30 + 4, torch.rand(50, generator=gen) * 20 + 4  # sub-pixel positions
    p = torch.stack([(pu - k.cx) / k.fx * 2.0, (pv - k.cy) / k.fy * 2.0, torch.full((50,), 2.0)], dim=-1)
    values = torch.rand(50, 2, generator=gen)

    def residual(xi: torch.Tensor) -> torch.Tensor:  # [6] float64 -> [50, 2], the channels at exp(xi) p
        return _channel_rows(_associate(se3_exp(xi), p, level, 0.1), values, level, k)[1]

    rows, r, usable = _channel_rows(_associate(torch.eye(4, dtype=torch.float64), p, level, 0.1), values, level, k)
    assert usable.all()
    exact = 0.01 * pu - 0.02 * pv + 0.3 - values[:, 0]  # the linear image at the projection, sub-pixel
    assert torch.allclose(r[:, 0], exact, atol=1e-5)
    reference = torch.autograd.functional.jacobian(residual, torch.zeros(6, dtype=torch.float64))  # [50, 2, 6]
    assert torch.allclose(rows, reference.float(), atol=1e-4)


def test_the_tracker_recovers_a_perturbed_pose_against_the_rendered_map(monkeypatch):
    gm, frame = target_frame(width=64, height=48)
    start = se3_exp(torch.tensor([0.03, -0.02, 0.02, 0.02, -0.03, 0.01], dtype=torch.float64)).numpy()
    monkeypatch.setattr(gauss_newton_module, "RENDERS", 2)
    result = gn_tracker(GaussNewtonSettings(iterations=(8,))).track(gm, frame, start, True)
    before = np.linalg.norm(start[:3, 3])
    after = np.linalg.norm(result.w2c[:3, 3])
    assert after < 0.1 * before, (before, after)
    assert result.renders == 3 and result.iterations == 16
    assert np.isfinite(result.loss) and result.valid_fraction > 0.3


def test_every_term_alone_and_the_adam_polish_move_towards_the_truth(monkeypatch):
    gm, frame = target_frame(width=64, height=48)
    start = se3_exp(torch.tensor([0.02, 0.0, 0.01, 0.0, 0.02, 0.0], dtype=torch.float64)).numpy()
    variants = {  # settings, and the tracker module's constants
        "depth": (GaussNewtonSettings(iterations=(6,), color_scale_m=0.0), {}),
        "colour and semantics": (GaussNewtonSettings(iterations=(6,), semantic_scale_m=0.05), {}),
        "rgb": (GaussNewtonSettings(iterations=(6,)), {"COLOR_CHANNELS": "rgb"}),
        "adam polish": (GaussNewtonSettings(iterations=(6,)), {"ADAM_STEPS": 3}),
        "colour on the finest level": (GaussNewtonSettings(iterations=(4, 4)), {"PHOTOMETRIC_LEVELS": 1}),
    }
    for name, (gn, constants) in variants.items():
        with monkeypatch.context() as patch:
            for constant, value in constants.items():
                patch.setattr(gauss_newton_module, constant, value)
            result = gn_tracker(gn).track(gm, frame, start, True)
        assert np.linalg.norm(result.w2c[:3, 3]) < 0.3 * np.linalg.norm(start[:3, 3]), name


def test_coarse_levels_align_depth_alone_below_the_photometric_levels(monkeypatch):
    gm, frame = target_frame(width=64, height=48)
    with torch.no_grad():
        out = render(gm, frame.intrinsics, torch.eye(4), SETTINGS)
    for keep, expected in ((0, [1, 1, 1]), (1, [0, 0, 1]), (2, [0, 1, 1]), (5, [1, 1, 1])):
        monkeypatch.setattr(gauss_newton_module, "PHOTOMETRIC_LEVELS", keep)
        tracker = gn_tracker(GaussNewtonSettings(iterations=(2, 2, 2)), sil_threshold=0.99)
        levels = tracker._reference(out, frame.intrinsics, 3, semantic=False)
        assert [level.num_channels for level in levels] == expected, keep


def test_with_keep_start_a_solve_that_explains_the_frame_worse_than_its_start_is_not_kept(monkeypatch):
    from sgs_slam_core.geometry.icp import DeviceAlignment
    from sgs_slam_core.slam.trackers import gauss_newton

    gm, frame = target_frame(width=64, height=48)
    start = se3_exp(torch.tensor([0.005, 0.0, 0.0, 0.0, 0.0, 0.0], dtype=torch.float64)).numpy()
    gn = GaussNewtonSettings(keep_start=True)
    solved = gn_tracker(gn).track(gm, frame, start, False)
    assert np.linalg.norm(solved.w2c[:3, 3]) < 0.5 * np.linalg.norm(start[:3, 3])  # a good solve is kept
    assert solved.rendering is not None

    jump = se3_exp(torch.tensor([0.2, 0.0, 0.0, 0.0, 0.0, 0.0], dtype=torch.float64))  # a solve gone wrong

    def astray(*args, **kwargs):  # align_device: checked against its start (keep_start off)
        return DeviceAlignment(jump, torch.tensor(1.0), torch.tensor(0.0), torch.tensor(1.0))

    monkeypatch.setattr(gauss_newton, "align_device", astray)
    monkeypatch.setattr(gauss_newton, "refine_device", lambda *args, **kwargs: jump)  # keep_start: unchecked
    kept = gn_tracker(gn).track(gm, frame, start, False)
    assert np.array_equal(kept.w2c, start) and np.isfinite(kept.loss) and kept.valid_fraction > 0.3
    assert kept.loss < solved.loss * 10 and kept.rendering is not None  # the start's own rendering
    astray_kept = gn_tracker(replace(gn, keep_start=False)).track(gm, frame, start, False)
    assert astray_kept.w2c[0, 3] == pytest.approx(start[0, 3] - 0.2, abs=1e-6)  # off: the solve always wins


def test_an_empty_map_keeps_the_prediction():
    gm, frame = target_frame(width=64, height=48)
    start = se3_exp(torch.tensor([0.0, 0.0, -10.0, 0.0, 0.0, 0.0], dtype=torch.float64)).numpy()  # map behind
    result = gn_tracker(GaussNewtonSettings()).track(gm, frame, start, False)
    assert np.array_equal(result.w2c, start) and result.loss == float("inf") and result.valid_fraction == 0.0


def test_a_start_on_the_device_costs_no_read_of_its_own_and_the_callers_values_come_back_with_the_pose():
    from bench.bench_dispatch import OpCounter

    gm, frame = target_frame(width=64, height=48)
    start = se3_exp(torch.tensor([0.01, -0.01, 0.0, 0.0, 0.01, 0.0], dtype=torch.float64)).numpy()
    tracker = gn_tracker(GaussNewtonSettings(iterations=(4,)))
    outcome = torch.tensor([1.0, 0.25, 0.003], dtype=torch.float64)
    results, reads = [], []
    for init, also in ((start, None), (torch.from_numpy(start), outcome)):
        counter = OpCounter()
        with counter.active():
            results.append(tracker.track(gm, frame, init, False, also_read=also))
        reads.append(counter.total[1])
    on_host, on_device = results
    assert np.array_equal(on_device.w2c, on_host.w2c) and on_device.loss == on_host.loss
    assert on_host.also_read is None and on_device.also_read.tolist() == [1.0, 0.25, 0.003]
    assert reads[1] == reads[0]  # the start and the caller's values come back in the pose's read
    behind = se3_exp(torch.tensor([0.0, 0.0, -10.0, 0.0, 0.0, 0.0], dtype=torch.float64))  # nothing explained
    kept = tracker.track(gm, frame, behind, False, also_read=outcome)
    assert np.array_equal(kept.w2c, behind.numpy()) and kept.also_read.tolist() == [1.0, 0.25, 0.003]
    adam = AdamTracker(TrackingSettings(adam=replace(TrackingSettings().adam, iterations=5)), TORCH)
    adam_host, adam_device = (
        adam.track(gm, frame, init, False, also_read=also)
        for init, also in ((start, None), (torch.from_numpy(start), outcome))
    )
    assert np.array_equal(adam_device.w2c, adam_host.w2c) and adam_device.also_read.tolist() == [1.0, 0.25, 0.003]


def test_a_feature_match_keeps_its_share_of_the_dense_terms_at_any_frame_size():
    """The dense terms sum over pixels, so a match weighs in proportion to the frame's pixel count."""
    from sgs_slam_core.slam.features import Landmarks

    tracker = gn_tracker(GaussNewtonSettings(feature_weight=10.0))
    marks = Landmarks(np.array([[0.1, 0.0, 2.0]]), np.array([[40.0, 30.0]]), 2.0)
    eye = torch.eye(4, dtype=torch.float64)
    weights = {
        (w, h): tracker._observations(marks, eye, Intrinsics(0.9 * w, 0.9 * w, w / 2, h / 2, w, h)).weight
        for w, h in ((160, 120), (320, 240), (640, 480), (80, 60))
    }
    assert weights == {(160, 120): 10.0, (320, 240): 40.0, (640, 480): 160.0, (80, 60): 2.5}
    assert tracker._observations(None, eye, Intrinsics(144.0, 144.0, 80.0, 60.0, 160, 120)) is None


def test_the_method_is_a_config_value_with_checked_settings():
    assert isinstance(build_tracker(TrackingSettings(), TORCH), AdamTracker)
    cfg = load_config("tum", overrides=["tracking.method=gauss_newton", "tracking.gauss_newton.huber_m=0.02"])
    assert isinstance(build_tracker(cfg.tracking, build_kernels(cfg.render, "cpu")), GaussNewtonTracker)
    for bad in (
        "tracking.method=lbfgs",
        "tracking.gauss_newton.iterations=[]",
        "tracking.gauss_newton.color_scale_m=-1",
        "tracking.gauss_newton.huber_m=0",
    ):
        with pytest.raises(ConfigError, match="tracking"):
            load_config("tum", overrides=[bad])


def test_slam_with_the_gauss_newton_tracker_follows_the_tiny_scene(tiny_scene):
    """At 64x48 with 15 mapping steps a frame both trackers stay within a few cm (Adam: 3.5-4.4 cm)."""
    tiny = open_dataset(tiny_scene)
    solve = [*FAST_SLAM, "tracking.method=gauss_newton", "tracking.gauss_newton.iterations=[6,4,3]"]
    slam = Slam(load_config("synthetic", overrides=solve), tiny.label_table)
    errors = []
    for i in range(8):
        step = slam.process(tiny[i])
        assert not step.track.failed
        errors.append(np.linalg.norm(step.c2w[:3, 3] - slam._gt_in_map_frame(tiny[i].gt_c2w)[:3, 3]))
    assert max(errors) < 0.09 and np.mean(errors) < 0.06, errors
    assert step.track.result.renders == 2 and step.track.result.iterations == 3  # one 64-pixel level: 3 steps


def test_the_compiled_level_matches_the_pytorch_reference():
    """Vertices, normals and validity of cpu/gauss_newton.cpp's level against geometry/icp.py's tensors."""
    from sgs_slam_core.geometry import icp
    from sgs_slam_core.kernels.cpu.extensions import GAUSS_NEWTON
    from sgs_slam_core.kernels.cpu.gauss_newton import icp_level

    if not GAUSS_NEWTON.is_available():
        pytest.skip(GAUSS_NEWTON.unavailable_reason())
    gm, frame = target_frame()
    k = frame.intrinsics
    with torch.no_grad():
        out = render(gm, k, se3_exp(torch.tensor([0.01, 0.0, -0.01, 0.01, 0.0, 0.02])), SETTINGS)
    depth = torch.where(out.silhouette > 0.99, out.depth, 0.0)
    depth[::7, ::5] = float("nan")  # invalid pixels inside the surface: their neighbours lose their normals
    for fast, slow in zip(icp.icp_pyramid(depth, k, 3, icp_level), icp.icp_pyramid(depth, k, 3), strict=True):
        assert fast.intrinsics == slow.intrinsics and fast.packed.shape == slow.packed.shape
        both = fast.valid & slow.valid
        assert slow.valid.sum() > 100 and (fast.valid != slow.valid).float().mean() < 1e-3
        assert torch.allclose(fast.vertices, torch.nan_to_num(slow.vertices), atol=1e-6)
        assert torch.allclose(fast.normals[both], slow.normals[both], atol=1e-5)
        assert not fast.normals[~fast.valid].any()


def _one_level_alignment(view: list[float]) -> tuple[IcpLevel, torch.Tensor, torch.Tensor]:
    """The target map rendered from ``view`` (an se(3) vector) as a one-level reference with intensity
    and a semantic channel, and the target frame's points [N, 3] and channels [N, 2]."""
    gm, frame = target_frame()
    k = frame.intrinsics
    with torch.no_grad():
        out = render(gm, k, se3_exp(torch.tensor(view)), SETTINGS)
    confident = out.silhouette > 0.99
    luma = torch.tensor([0.3, 0.6, 0.1])
    channels = torch.stack([out.color @ luma, out.semantic[..., 0]], dim=-1) * 0.1  # [H, W, 2]
    ref = icp_pyramid(torch.where(confident, out.depth, 0.0), k, 1)[0]
    ref = ref.with_channels(channel_pyramid(channels, confident, 1)[0])
    points = vertex_map(frame.depth, k).reshape(-1, 3)
    values = source_channels(torch.stack([frame.rgb @ luma, frame.semantic[..., 0]], dim=-1) * 0.1, 1)[0]
    return ref, points, values


def test_the_compiled_steps_match_the_pytorch_steps():
    """A level's damped updates in one compiled call against geometry/icp.py's step loop."""
    from sgs_slam_core.geometry import icp
    from sgs_slam_core.kernels.cpu.extensions import GAUSS_NEWTON
    from sgs_slam_core.kernels.cpu.gauss_newton import icp_steps

    if not GAUSS_NEWTON.is_available():
        pytest.skip(GAUSS_NEWTON.unavailable_reason())
    ref, points, values = _one_level_alignment([0.02, 0.0, -0.01, 0.01, 0.0, 0.02])
    start = torch.eye(4, dtype=torch.float64)
    noise_weights = DepthNoise().weights(points[:, 2])
    for level, vals in ((icp.IcpLevel(ref.intrinsics, ref.packed[:, :7]), None), (ref, values)):
        for damping, weights in ((1e-4, None), (10.0, None), (1e-4, noise_weights)):
            s = icp.IcpSettings(max_distance_m=0.2, damping=damping)
            slow = start
            for _ in range(4):
                slow = icp._gauss_newton_step(slow, icp._LevelSource(points, vals, weights), level, s)
            fast = icp_steps(start, points, vals, weights, level, s, 4)
            assert not torch.allclose(slow, start, atol=1e-4)  # the steps moved the pose
            assert torch.allclose(fast, slow, atol=1e-6), (fast - slow).abs().max()
    assert torch.equal(icp_steps(start, points, None, None, ref, s, 0), start)


def test_the_compiled_step_matches_the_pytorch_reference():
    """Normal equations and truncated cost of cpu/gauss_newton.cpp against geometry/icp.py's tensors."""
    from sgs_slam_core.geometry import icp
    from sgs_slam_core.kernels.cpu.extensions import GAUSS_NEWTON
    from sgs_slam_core.kernels.cpu.gauss_newton import icp_terms

    if not GAUSS_NEWTON.is_available():
        pytest.skip(GAUSS_NEWTON.unavailable_reason())
    ref, points, values = _one_level_alignment([0.01, 0.0, -0.01, 0.01, 0.0, 0.02])
    s = icp.IcpSettings(max_distance_m=0.2)
    pose = se3_exp(torch.tensor([0.005, 0.0, 0.0, 0.0, 0.01, 0.0], dtype=torch.float64))
    depth_only = icp.IcpLevel(ref.intrinsics, ref.packed[:, :7])
    noise_weights = DepthNoise().weights(points[:, 2])
    for level, vals, weights in ((depth_only, None, None), (ref, values, None), (ref, values, noise_weights)):
        terms = icp._terms(icp_terms, pose, icp._LevelSource(points, vals, weights), level, s)
        normal = icp._normal_matrix(pose, icp._LevelSource(points, vals, weights), level, s)
        assert torch.allclose(terms[:49].reshape(7, 7), normal, rtol=1e-4, atol=1e-6 * float(normal.abs().max()))
        a = icp._associate(pose, points, level, s.max_distance_m, weights)
        cost = icp._truncated_cost(a.weighted, a.inliers, points[:, 2] > 0, s)
        if vals is not None:
            cost = cost + icp._channel_cost(a, vals, level, s)
        assert a.inliers.sum() > 500 and terms[50] == a.inliers.sum() and terms[52] == (points[:, 2] > 0).sum()
        assert torch.allclose(terms[49], cost, rtol=1e-5)
        assert torch.allclose(terms[51], (a.residual.double().square() * a.inliers).sum(), rtol=1e-5)


def test_without_steps_the_start_is_judged_at_one_rendering():
    gm, frame = target_frame(width=64, height=48)
    start = se3_exp(torch.tensor([0.005, 0.0, 0.0, 0.0, 0.0, 0.0], dtype=torch.float64)).numpy()
    for keep_start in (False, True):
        gn = GaussNewtonSettings(iterations=(0, 0), keep_start=keep_start)
        result = gn_tracker(gn).track(gm, frame, start, False)
        assert np.array_equal(result.w2c, start) and result.renders == 1 and result.iterations == 0
        assert np.isfinite(result.loss) and result.valid_fraction > 0.3 and result.rendering is not None
    moved = gn_tracker(replace(gn, iterations=(2, 2))).track(gm, frame, start, False)
    assert moved.renders == 2 and moved.loss < result.loss  # with steps it solves and renders again
