import numpy as np
import pytest

from sgs_slam_core.datasets import ReplicaDataset, open_dataset
from sgs_slam_core.errors import ConfigError, DatasetError
from sgs_slam_core.geometry import Intrinsics
from sgs_slam_core.synthetic import build_room, generate, look_at, make_trajectory, preset_config, raycast
from sgs_slam_core.synthetic.raycast import _camera_rays, _cast


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    return generate(tmp_path_factory.mktemp("tiny") / "seq", preset_config("tiny"))


def test_tiny_preset_loads_with_the_replica_reader(tiny):
    ds = open_dataset(tiny)
    assert isinstance(ds, ReplicaDataset) and len(ds) == 12
    assert (ds.intrinsics.width, ds.intrinsics.height) == (64, 48)
    f = ds[0]
    assert f.valid_depth_fraction == 1.0  # a closed room: every ray hits something
    assert f.depth.min() > 0.3 and f.depth.max() < 6.5
    assert len(ds.label_table) - 1 >= 8  # at least 8 semantic classes besides "unlabelled"
    assert len(np.unique(np.concatenate([ds[i].labels.ravel() for i in range(12)]))) >= 5
    assert ds.label_table.name_of(7) == "table"


def test_generation_is_deterministic_by_seed(tmp_path):
    a = generate(tmp_path / "a", preset_config("tiny", frames=2))
    b = generate(tmp_path / "b", preset_config("tiny", frames=2))
    c = generate(tmp_path / "c", preset_config("tiny", frames=2, seed=5))
    fa, fb, fc = (ReplicaDataset(p)[1] for p in (a, b, c))
    assert np.array_equal(fa.rgb, fb.rgb) and np.array_equal(fa.depth, fb.depth)
    assert not np.array_equal(fa.rgb, fc.rgb)


def test_depth_is_consistent_with_poses_and_intrinsics():
    """Back-project frame 0 with its pose into frame 3; a ray cast through the exact (sub-pixel)
    projection in frame 3 returns the same depth wherever the point is not occluded."""
    scene = build_room(0)
    k = Intrinsics(60.0, 60.0, 39.5, 29.5, 80, 60)
    poses = make_trajectory("orbit", 4, scene.center, step_deg=3.0)
    _, d0, _ = raycast(scene, k, poses[0], supersample=1)
    v, u = np.mgrid[0:60, 0:80]
    pts = np.stack([(u - k.cx) / k.fx * d0, (v - k.cy) / k.fy * d0, d0], -1).reshape(-1, 3)
    world = pts @ poses[0][:3, :3].T + poses[0][:3, 3]
    cam3 = (world - poses[3][:3, 3]) @ poses[3][:3, :3]
    uu, vv = cam3[:, 0] / cam3[:, 2] * k.fx + k.cx, cam3[:, 1] / cam3[:, 2] * k.fy + k.cy
    inside = (uu >= 0) & (uu < 79) & (vv >= 0) & (vv < 59)
    t, *_ = _cast(scene, poses[3][:3, 3], _camera_rays(k, poses[3][:3, :3], uu[inside], vv[inside]), 0)
    diff = np.abs(t - cam3[inside, 2])
    assert inside.mean() > 0.5
    assert np.median(diff) < 1e-6 and (diff < 1e-4).mean() > 0.95  # the rest are occluded in frame 3


def test_look_at_is_a_proper_optical_frame():
    pose = look_at(np.array([0.0, 0.0, 1.5]), np.array([1.0, 0.0, 1.5]))
    assert np.allclose(pose[:3, :3] @ pose[:3, :3].T, np.eye(3)) and np.linalg.det(pose[:3, :3]) == pytest.approx(1)
    assert np.allclose(pose[:3, 2], [1, 0, 0])  # z forward
    assert np.allclose(pose[:3, 1], [0, 0, -1])  # y down


@pytest.mark.parametrize("kind", ["orbit", "walk", "look"])
def test_trajectories_are_smooth(kind):
    poses = np.stack(make_trajectory(kind, 60, build_room(0).center, step_deg=1.5))
    rel = np.linalg.inv(poses[:-1]) @ poses[1:]
    angles = np.degrees(np.arccos(np.clip((np.trace(rel[:, :3, :3], axis1=1, axis2=2) - 1) / 2, -1, 1)))
    steps = np.linalg.norm(rel[:, :3, 3], axis=1)
    assert angles.max() < 3.0 and steps.max() < 0.06
    assert angles.mean() > 0.3  # the camera does move


def test_noise_options(tmp_path):
    clean = ReplicaDataset(generate(tmp_path / "clean", preset_config("tiny", frames=1)))[0]
    noisy = ReplicaDataset(
        generate(
            tmp_path / "noisy",
            preset_config("tiny", frames=1, depth_noise=1.0, depth_holes=0.1, label_noise=0.1, label_erosion=1),
        )
    )[0]
    holes = noisy.depth == 0
    assert 0.07 < holes.mean() < 0.13
    err = np.abs(noisy.depth - clean.depth)[~holes]
    assert 0.0005 < err.mean() < 0.02  # Kinect-like millimetre noise at 1-5 m
    changed = noisy.labels != clean.labels
    assert 0.1 < changed.mean() < 0.6 and (noisy.labels[changed] == 0).mean() > 0.3


def test_bad_config_and_existing_output(tmp_path):
    with pytest.raises(ConfigError):
        preset_config("tiny", depth_holes=1.5)
    with pytest.raises(ConfigError, match="unknown synthetic preset"):
        preset_config("huge")
    generate(tmp_path / "x", preset_config("tiny", frames=1))
    with pytest.raises(DatasetError, match="not empty"):
        generate(tmp_path / "x", preset_config("tiny", frames=1))
