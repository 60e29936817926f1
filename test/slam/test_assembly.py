"""The parts ``Slam`` is assembled from: the map frame policy, the motion model, the config sections."""

import threading

import numpy as np
import pytest
import torch

from sgs_slam_core.config import load_config
from sgs_slam_core.config.sections import MapFrameSettings, MotionSettings
from sgs_slam_core.datasets import open_dataset
from sgs_slam_core.errors import ConfigError
from sgs_slam_core.frame import Frame
from sgs_slam_core.frame_data import FrameTensors
from sgs_slam_core.geometry import Intrinsics, se3_exp
from sgs_slam_core.geometry.gravity import OPTICAL_IN_BODY, MapAlignment, initial_map_pose, pose_from_xyz_rpy
from sgs_slam_core.labels import LabelTable
from sgs_slam_core.semantics import SemanticCodec, SemanticSettings
from sgs_slam_core.slam.map_frame import MapFramePolicy
from sgs_slam_core.slam.motion import MotionModel
from sgs_slam_core.slam.system import Slam

from ..conftest import FAST_SLAM

K = Intrinsics(40.0, 40.0, 15.5, 11.5, 32, 24)


def frame_data(depth_m: float = 2.0) -> FrameTensors:
    codec = SemanticCodec(SemanticSettings(), LabelTable.nyu40())
    depth = np.full((24, 32), depth_m, np.float32)
    return FrameTensors.from_arrays(0, K, np.zeros((24, 32, 3), np.uint8), depth, None, codec, torch.device("cpu"))


def test_slam_levels_the_map_on_the_floor_as_the_nodes_ask_and_keeps_the_optical_frame_by_default(tiny_scene):
    frame = open_dataset(tiny_scene)[0]
    level = Slam(load_config("synthetic", None, [*FAST_SLAM, "device=cpu", "map_frame.alignment=floor"]))
    first = level.track(frame)
    mount = pose_from_xyz_rpy(OPTICAL_IN_BODY)
    expected, plane = initial_map_pose(MapAlignment.FLOOR, frame.depth, frame.intrinsics, mount)
    assert plane is not None and first.map_frame.alignment == "floor"
    assert np.array_equal(first.map_frame.floor.normal, plane.normal)
    assert np.array_equal(first.c2w, expected) and abs(first.c2w[2, 3] - plane.height_m) < 1e-9  # z up, on the floor
    plain = Slam(load_config("synthetic", None, [*FAST_SLAM, "device=cpu"])).track(frame)
    assert np.array_equal(plain.c2w, np.eye(4)) and plain.map_frame.alignment == "optical"
    level.reset()  # a new run chooses again
    assert np.array_equal(level.track(frame).c2w, expected)


def test_a_pose_given_to_slam_wins_over_the_policy(tiny_scene):
    frame = open_dataset(tiny_scene)[0]
    given = se3_exp(torch.tensor([0.1, 0.2, 0.3, 0.0, 0.1, 0.0], dtype=torch.float64)).numpy()
    slam = Slam(load_config("synthetic", None, [*FAST_SLAM, "device=cpu", "map_frame.alignment=floor"]), None, given)
    first = slam.track(frame)
    assert np.array_equal(first.c2w, given) and first.map_frame.alignment == "given"


def test_a_floorless_view_falls_back_to_the_mount_and_says_so():
    policy = MapFramePolicy(MapFrameSettings(alignment="floor"))
    wall = Frame(np.zeros((24, 32, 3), np.uint8), np.full((24, 32), 2.0, np.float32), K)  # a wall straight ahead
    choice = policy.choose(wall)
    assert choice.floor is None and choice.alignment == "mount (no floor in the first frame)"


def test_the_motion_model_repeats_the_last_motion_and_scales_it_by_the_time_gap():
    motion = MotionModel(MotionSettings(icp_iterations=()), np.eye(4))
    step = se3_exp(torch.tensor([0.0, 0.0, 0.05, 0.0, 0.0, 0.0], dtype=torch.float64)).numpy()
    assert np.array_equal(motion.predict(0, frame_data()), np.eye(4))  # nothing seen yet: the first pose
    motion.observe(0, np.eye(4), None)
    motion.observe(33_000_000, step, None)
    assert np.allclose(motion.predict(66_000_000, frame_data()), step @ step)  # constant velocity
    assert np.allclose(motion.predict(132_000_000, frame_data())[2, 3], 0.05 * 4)  # two frames dropped: 3 steps on
    still = MotionModel(MotionSettings(constant_velocity=False, icp_iterations=()), np.eye(4))
    still.observe(0, np.eye(4), None)
    still.observe(33_000_000, step, None)
    assert np.array_equal(still.predict(66_000_000, frame_data()), step)


def test_the_motion_model_runs_the_icp_only_after_a_gap_and_resumes_a_saved_run():
    motion = MotionModel(MotionSettings(), np.eye(4))
    assert motion.uses_icp and not MotionModel(MotionSettings(icp_iterations=()), np.eye(4)).uses_icp
    resumed = MotionModel(MotionSettings(icp_iterations=()), np.eye(4))
    last = se3_exp(torch.tensor([0.3, 0.0, 0.0, 0.0, 0.0, 0.0], dtype=torch.float64)).numpy()
    resumed.resume([np.eye(4), last])
    assert np.allclose(resumed.predict(0, frame_data()), last @ last)  # a resumed map goes on moving


def test_keys_of_other_sections_are_unknown_where_they_are_not():
    config = load_config("tum", None, ["motion.icp_min_gap=0", "motion.constant_velocity=false"])
    assert config.motion.icp_min_gap == 0 and not config.motion.constant_velocity
    with pytest.raises(ConfigError, match=r"unknown config key tracking\.icp_min_gap"):
        load_config("tum", None, ["tracking.icp_min_gap=0"])
    with pytest.raises(ConfigError, match="camera_mount"):
        load_config("tum", None, ["map_frame.camera_mount=[0, 0, 0, 1]"])


def test_slam_holds_no_locks_or_threads():
    slam = Slam(load_config("synthetic", None, [*FAST_SLAM, "device=cpu"]))
    kinds = (type(threading.Lock()), type(threading.RLock()), threading.Condition, threading.Thread)
    assert not [name for name, value in vars(slam).items() if isinstance(value, kinds)]


def test_densification_reuses_the_gauss_newton_trackers_rendering_while_the_map_is_unchanged(tiny_scene, monkeypatch):
    from sgs_slam_core.slam import system

    tiny = open_dataset(tiny_scene)
    solve = [*FAST_SLAM, "tracking.method=gauss_newton", "tracking.gauss_newton.iterations=[6,4,3]"]
    slam = Slam(load_config("synthetic", None, solve), tiny.label_table)
    slam.process(tiny[0])
    seen = []

    def spy(*args, **kwargs):
        seen.append(kwargs["rendered"])
        return densify_frame(*args, **kwargs)

    densify_frame = system.densify_frame
    monkeypatch.setattr(system, "densify_frame", spy)
    tracked = slam.track(tiny[1])
    rendering = tracked.result.rendering
    assert rendering is not None and rendering.gaussians is slam.gaussians
    expected = densify_frame(slam.gaussians, tracked.frame_data, tiny[1], tracked.c2w, **_densify_args(slam))
    added = slam.map(tiny[1], tracked).added
    assert seen[-1] is rendering.out
    # as many as when rendered again (where the pose round-trips through float64, a pixel may flip)
    assert expected[1] > 0 and abs(added - expected[1]) <= 0.02 * expected[1], (added, expected[1])

    again = slam.track(tiny[2])
    slam.gaussians = slam.gaussians.with_tensors()  # a new map object (as after an edit): not the one rendered
    slam.map(tiny[2], again)
    assert seen[-1] is None


def _densify_args(slam: Slam) -> dict:
    return {
        "settings": slam.config.densify,
        "kernels": slam.kernels,
        "codec": slam.codec,
        "edits": slam.edits,
        "generator": torch.Generator(device="cpu").manual_seed(slam.config.seed),
    }


def test_steps_kept_by_callers_hold_no_frame_tensors_or_renderings(tiny_scene):
    tiny = open_dataset(tiny_scene)
    slam = Slam(load_config("synthetic", None, [*FAST_SLAM, "tracking.method=gauss_newton"]), tiny.label_table)
    steps = [slam.process(tiny[i]) for i in range(3)]
    assert all(s.track.frame_data is None for s in steps)
    assert steps[2].track.result is not None and steps[2].track.result.rendering is None
