"""Depth ICP: recovers a known motion inside a ray-cast box, keeps unconstrained directions, fails safe."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from sgs_slam_core.errors import ShapeError
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.geometry.icp import (
    IcpSettings,
    Observations,
    _observation_rows,
    align_depth,
    icp_pyramid,
    refine_device,
)
from sgs_slam_core.geometry.se3 import se3_exp
from sgs_slam_core.labels import LabelTable
from sgs_slam_core.synthetic.primitives import Box, RoomShell
from sgs_slam_core.synthetic.raycast import raycast
from sgs_slam_core.synthetic.room import Scene
from sgs_slam_core.synthetic.textures import Material

K = Intrinsics(fx=80.0, fy=80.0, cx=79.5, cy=59.5, width=160, height=120)
_PLAIN = Material(base=(0.5, 0.5, 0.5))
# the inside of a box around the camera (m), and a single far wall (the camera looks along +z)
BOX = Scene(
    (RoomShell(1, _PLAIN, lo=(-2.0, -1.2, -1.0), hi=(1.5, 1.0, 3.0)),),
    LabelTable.nyu40(),
    (-2.0, -1.2, -1.0),
    (1.5, 1.0, 3.0),
)
WALL = Scene(
    (Box(1, _PLAIN, center=(0.0, 0.0, 3.05), half=(20.0, 20.0, 0.05)),),
    LabelTable.nyu40(),
    (-20.0, -20.0, 3.0),
    (20.0, 20.0, 3.1),
)


def room_depth(c2w: np.ndarray, scene: Scene = BOX) -> torch.Tensor:  # [H, W] m, 0 where no hit
    return torch.from_numpy(raycast(scene, K, c2w, supersample=1)[1])


def pose(rho: tuple[float, float, float], phi_deg: tuple[float, float, float]) -> np.ndarray:  # [4, 4]
    xi = torch.tensor([*rho, *(math.radians(a) for a in phi_deg)], dtype=torch.float64)
    return se3_exp(xi).numpy()


def errors(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:  # (m, deg)
    cos = np.clip((np.trace(a[:3, :3].T @ b[:3, :3]) - 1) / 2, -1, 1)
    return float(np.linalg.norm(a[:3, 3] - b[:3, 3])), math.degrees(math.acos(cos))


DEFAULT = IcpSettings()


def align(ref_c2w, src_c2w, init, s=DEFAULT, scene=BOX):
    ref = icp_pyramid(room_depth(ref_c2w, scene), K, len(s.steps_for(K.width)))
    return align_depth(room_depth(src_c2w, scene), K, ref, torch.as_tensor(init), s)


def test_recovers_a_motion_of_several_frames_from_no_prior():
    ref_c2w = pose((0.1, -0.05, 0.2), (2.0, -5.0, 1.0))
    motion = pose((0.06, 0.02, -0.05), (1.5, 3.0, -2.0))  # ~8 cm and ~4 degrees: three fast frames
    res = align(ref_c2w, ref_c2w @ motion, np.eye(4))  # the default steps: a start for tracking
    trans, rot = errors(res.src_to_ref.numpy(), motion)
    assert trans < 0.01 and rot < 0.05  # from 7.5 cm and 3.6 degrees off
    assert res.inlier_fraction > 0.8 and res.rms_m < 0.005
    res = align(ref_c2w, ref_c2w @ motion, np.eye(4), IcpSettings(iterations=(10, 10, 10)))  # converged
    trans, rot = errors(res.src_to_ref.numpy(), motion)
    assert trans < 5e-4 and rot < 0.01 and res.rms_m < 0.002


def test_directions_the_geometry_does_not_constrain_stay_at_the_prediction():
    """Only a flat wall in view: sliding along it changes nothing, so the prediction's slide is kept."""
    motion = pose((0.0, 0.0, 0.04), (0.0, 0.0, 0.0))
    init = pose((0.03, 0.0, 0.0), (0.0, 0.0, 0.0))  # right depth-wise, 3 cm off along the wall
    res = align(np.eye(4), motion, init, scene=WALL).src_to_ref.numpy()
    assert abs(res[2, 3] - 0.04) < 1e-3  # the distance to the wall is recovered
    assert abs(res[0, 3] - 0.03) < 2e-3  # the slide stays where the prediction put it


def test_no_overlap_keeps_the_initial_pose_and_reports_no_inliers():
    s = IcpSettings()
    empty = icp_pyramid(torch.zeros(K.shape), K, len(s.steps_for(K.width)))
    init = pose((0.01, 0.0, 0.0), (0.0, 1.0, 0.0))
    res = align_depth(room_depth(np.eye(4)), K, empty, torch.as_tensor(init), s)
    assert res.inlier_fraction == 0.0 and res.rms_m == math.inf
    np.testing.assert_allclose(res.src_to_ref.numpy(), init, atol=1e-9)


def test_coarse_levels_narrower_than_the_minimum_are_left_out():
    s = IcpSettings(iterations=(6, 4, 3), min_width=40)
    assert s.steps_for(160) == (6, 4, 3)  # 40 px at the coarsest level
    assert s.steps_for(100) == (4, 3)
    assert s.steps_for(64) == (3,)
    with pytest.raises(ShapeError, match="levels"):
        two_levels = icp_pyramid(torch.ones(K.shape), K, 2)
        align_depth(torch.ones(K.shape), K, two_levels, torch.eye(4, dtype=torch.float64), s)


def test_float64_pose_on_the_depth_device():
    s = IcpSettings()
    res = align(np.eye(4), pose((0.01, 0.0, 0.0), (0.0, 0.0, 0.0)), np.eye(4), s)
    assert res.src_to_ref.dtype == torch.float64 and res.src_to_ref.device.type == "cpu"


def test_a_result_worse_than_the_start_at_full_resolution_is_not_returned(monkeypatch):
    """A biased coarse level (as on the room's frames 172-175) must not move a right start away."""
    from sgs_slam_core.geometry import icp

    ref_c2w = pose((0.1, -0.05, 0.2), (2.0, -5.0, 1.0))
    motion = pose((0.02, 0.0, 0.01), (0.5, 1.0, 0.0))
    slide = torch.as_tensor(pose((0.05, 0.0, 0.0), (0.0, 0.0, 0.0)))
    monkeypatch.setattr(icp, "_gauss_newton_step", lambda p, *_: slide @ p)  # every step slides 5 cm
    res = align(ref_c2w, ref_c2w @ motion, motion)
    assert np.allclose(res.src_to_ref.numpy(), motion)  # the start, not 65 cm away
    assert res.rms_m < 0.005


def test_refine_device_returns_the_steps_result_unchecked(monkeypatch):
    """The same sliding steps: refine_device hands back where they went; align_device keeps the start."""
    from sgs_slam_core.geometry import icp

    ref_c2w = pose((0.1, -0.05, 0.2), (2.0, -5.0, 1.0))
    motion = pose((0.02, 0.0, 0.01), (0.5, 1.0, 0.0))
    s = IcpSettings()
    ref = icp_pyramid(room_depth(ref_c2w), K, len(s.steps_for(K.width)))
    depth, start = room_depth(ref_c2w @ motion), torch.as_tensor(motion)
    exact = icp.refine_device(depth, K, ref, start, s)
    assert torch.allclose(exact, icp.align_device(depth, K, ref, start, s).src_to_ref)  # a good solve: the same
    slide = torch.as_tensor(pose((0.05, 0.0, 0.0), (0.0, 0.0, 0.0)))
    monkeypatch.setattr(icp, "_gauss_newton_step", lambda p, *_: slide @ p)
    moved = icp.refine_device(depth, K, ref, start, s)
    steps = sum(s.steps_for(K.width))
    assert torch.allclose(moved, torch.linalg.matrix_power(slide, steps) @ start)
    assert torch.allclose(icp.align_device(depth, K, ref, start, s).src_to_ref, start)


def test_the_source_levels_are_the_full_vertex_map_subsampled_bit_for_bit():
    """Each level's points from one vertex map equal that level's own vertex map, odd sizes included."""
    from sgs_slam_core.geometry import icp
    from sgs_slam_core.geometry.camera import vertex_map

    for width, height in ((160, 120), (81, 61), (47, 33)):
        k = Intrinsics(0.9 * width + 0.123, 0.87 * width + 0.77, width / 2 - 0.37, height / 2 + 0.211, width, height)
        depth = torch.rand(height, width, generator=torch.Generator().manual_seed(width)) * 4
        depth[depth < 0.3] = 0.0
        depth[0, 0] = float("nan")
        own = [vertex_map(d, level).reshape(-1, 3) for d, level in icp._scales(depth, k, 4)]
        for a, b in zip(icp._source_points(vertex_map(depth, k), 4), own, strict=True):
            assert torch.equal(a, b)


def test_the_erosion_is_max_pooling_of_the_negated_mask():
    from sgs_slam_core.geometry import icp

    generator = torch.Generator().manual_seed(0)
    for shape in ((120, 160), (31, 41), (3, 3), (1, 5)):
        for p in (0.5, 0.9, 0.99):
            mask = (torch.rand(1, 1, *shape, generator=generator) < p).float()
            pooled = -torch.nn.functional.max_pool2d(-mask, 3, stride=1, padding=1)
            assert torch.equal(icp._erode(mask), pooled)


def test_a_channel_pyramid_of_the_finest_levels_ends_a_full_one():
    """The tracker builds only the levels that carry photometric terms; they equal a full pyramid's."""
    from sgs_slam_core.geometry.icp import channel_pyramid, source_channels

    generator = torch.Generator().manual_seed(1)
    image = torch.rand(120, 160, 2, generator=generator)
    valid = torch.rand(120, 160, generator=generator) < 0.95
    full, finest = channel_pyramid(image, valid, 3), channel_pyramid(image, valid, 2)
    assert all(torch.equal(a, b) for a, b in zip(full[1:], finest, strict=True))
    full, finest = source_channels(image, 3), source_channels(image, 1)
    assert torch.equal(full[-1], finest[0])


def wall_observations(src_c2w: np.ndarray, weight: float = 10.0) -> Observations:
    """Points on the wall (reference frame = the identity camera) and where the camera at ``src_c2w`` sees them."""
    rng = np.random.default_rng(0)
    points = np.stack([rng.uniform(-1.0, 1.0, 60), rng.uniform(-0.8, 0.8, 60), np.full(60, 3.0)], axis=1)
    cam = (points - src_c2w[:3, 3]) @ src_c2w[:3, :3]  # into the source camera
    pixels = np.stack([cam[:, 0] / cam[:, 2] * K.fx + K.cx, cam[:, 1] / cam[:, 2] * K.fy + K.cy], axis=1)
    return Observations(torch.as_tensor(points), torch.as_tensor(pixels), weight, 2.0)


def test_observation_rows_are_the_derivative_of_the_reprojection():
    """At the pose the pixels were seen from (residuals 0, so the rows' metre scale is a constant there)."""
    src_to_ref = pose((0.02, -0.01, 0.03), (1.0, -2.0, 0.5))
    obs = wall_observations(src_to_ref)  # the reference camera is the identity
    src_to_ref = torch.as_tensor(src_to_ref)
    rows, _ = _observation_rows(src_to_ref, obs, K)
    eps = 1e-6
    for j in range(6):
        xi = torch.zeros(6, dtype=torch.float64)
        xi[j] = eps
        plus, _ = _observation_rows(se3_exp(xi) @ src_to_ref, obs, K)
        minus, _ = _observation_rows(se3_exp(-xi) @ src_to_ref, obs, K)
        numeric = (plus[:, 6] - minus[:, 6]) / (2 * eps)
        torch.testing.assert_close(rows[:, j], numeric, rtol=1e-4, atol=1e-7)


def test_points_hold_the_slide_a_wall_leaves_free():
    """The flat wall again: feature points seen by the camera fix the slide the depth cannot."""
    motion = pose((0.0, 0.0, 0.04), (0.0, 0.0, 0.0))
    init = pose((0.03, 0.0, 0.0), (0.0, 0.0, 0.0))
    ref = icp_pyramid(room_depth(np.eye(4), WALL), K, len(DEFAULT.steps_for(K.width)))
    obs = wall_observations(motion)
    res = refine_device(room_depth(motion, WALL), K, ref, torch.as_tensor(init), DEFAULT, observations=obs)
    trans, rot = errors(res.numpy(), motion)
    assert trans < 2e-3 and rot < 0.05  # the slide is gone, the distance kept
    assert abs(res[2, 3].item() - 0.04) < 1e-3


def test_the_compiled_terms_give_the_same_joint_steps():
    from sgs_slam_core.kernels.cpu.extensions import GAUSS_NEWTON
    from sgs_slam_core.kernels.cpu.gauss_newton import ICP_KERNELS

    if not GAUSS_NEWTON.is_available():
        pytest.skip(GAUSS_NEWTON.unavailable_reason())
    motion = pose((0.01, 0.0, 0.04), (0.5, 0.0, 0.0))
    init = torch.as_tensor(pose((0.03, 0.0, 0.0), (0.0, 0.0, 0.0)))
    ref = icp_pyramid(room_depth(np.eye(4), WALL), K, len(DEFAULT.steps_for(K.width)))
    obs = wall_observations(motion)
    depth = room_depth(motion, WALL)
    slow = refine_device(depth, K, ref, init, DEFAULT, observations=obs)
    fast = refine_device(depth, K, ref, init, DEFAULT, kernels=ICP_KERNELS, observations=obs)
    assert torch.allclose(fast, slow, atol=1e-5)
    assert errors(fast.numpy(), motion)[0] < 2e-3
