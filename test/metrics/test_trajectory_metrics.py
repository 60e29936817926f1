import numpy as np
import pytest
import torch
from evo.core import metrics
from evo.core.trajectory import PosePath3D
from evo.main_ape import ape

from sgs_slam_core.datasets import open_dataset
from sgs_slam_core.errors import ShapeError
from sgs_slam_core.geometry import se3_exp
from sgs_slam_core.metrics import (
    ate,
    ate_paper,
    read_tum_trajectory,
    rpe,
    umeyama,
    write_tum_trajectory,
)


def random_trajectory(n: int, seed: int = 0) -> np.ndarray:
    g = torch.Generator().manual_seed(seed)
    steps = se3_exp(
        torch.randn(n, 6, generator=g, dtype=torch.float64) * torch.tensor([0.05] * 3 + [0.03] * 3, dtype=torch.float64)
    )
    poses = [torch.eye(4, dtype=torch.float64)]
    for s in steps[1:]:
        poses.append(poses[-1] @ s)
    return torch.stack(poses).numpy()


def rigid(seed: int = 1) -> np.ndarray:
    g = torch.Generator().manual_seed(seed)
    return se3_exp(torch.randn(6, generator=g, dtype=torch.float64)).numpy()


def test_umeyama_recovers_a_rigid_transform_and_scale():
    pts = np.random.default_rng(0).normal(size=(50, 3))
    t = rigid()
    rot, trans, s = umeyama(pts, 2.0 * pts @ t[:3, :3].T + t[:3, 3], with_scale=True)
    assert np.allclose(rot, t[:3, :3]) and np.allclose(trans, t[:3, 3]) and s == pytest.approx(2.0)


def test_ate_is_zero_for_a_rigidly_moved_estimate_and_sees_translation_offsets_unaligned():
    gt = random_trajectory(100)
    est = rigid() @ gt
    assert ate(est, gt).rmse < 1e-10
    assert ate_paper(est, gt).mean < 1e-10
    shifted = gt.copy()
    shifted[:, :3, 3] += [0.1, 0.0, 0.0]
    assert ate(shifted, gt).rmse < 1e-12
    assert ate(shifted, gt, align=False).rmse == pytest.approx(0.1)


def test_ate_of_known_noise():
    gt = random_trajectory(4000, seed=2)
    est = gt.copy()
    sigma = 0.01
    est[:, :3, 3] += np.random.default_rng(3).normal(scale=sigma, size=(4000, 3))
    # RMSE of 3D isotropic noise is sigma * sqrt(3); alignment absorbs a negligible part of it.
    assert ate(est, gt).rmse == pytest.approx(sigma * np.sqrt(3), rel=0.03)


def evo_ape_rmse(est: np.ndarray, gt: np.ndarray) -> float:
    result = ape(
        PosePath3D(poses_se3=list(gt)),
        PosePath3D(poses_se3=list(est)),
        metrics.PoseRelation.translation_part,
        align=True,
        correct_scale=False,
    )
    return float(result.stats["rmse"])


def test_ate_matches_evo_on_random_trajectories():
    gt = random_trajectory(300, seed=4)
    est = random_trajectory(300, seed=5)  # unrelated: large errors, a hard alignment case
    assert ate(est, gt).rmse == pytest.approx(evo_ape_rmse(est, gt), abs=1e-6)
    noisy = rigid(6) @ gt
    noisy[:, :3, 3] += np.random.default_rng(7).normal(scale=0.02, size=(300, 3))
    assert ate(noisy, gt).rmse == pytest.approx(evo_ape_rmse(noisy, gt), abs=1e-6)


@pytest.mark.data
def test_ate_matches_evo_on_the_real_tum_trajectory(tum_teddy):
    gt = np.stack([r.gt_c2w for r in open_dataset(tum_teddy).records if r.gt_c2w is not None])
    est = gt.copy()
    est[:, :3, 3] += np.random.default_rng(8).normal(scale=0.01, size=est[:, :3, 3].shape)
    est = rigid(9) @ est
    assert ate(est, gt).rmse == pytest.approx(evo_ape_rmse(est, gt), abs=1e-6)


def test_ate_paper_differs_from_standard_ate_and_is_a_mean():
    gt = random_trajectory(200, seed=10)
    est = gt.copy()
    est[:, :3, 3] += np.random.default_rng(11).normal(scale=0.02, size=(200, 3))
    paper, standard = ate_paper(est, gt), ate(est, gt)
    assert paper.mean == pytest.approx(paper.errors.mean()) and paper.mean < paper.rmse
    assert abs(paper.mean - standard.rmse) > 1e-4


def test_rpe():
    gt = random_trajectory(50, seed=12)
    assert rpe(rigid() @ gt, gt).trans_rmse < 1e-10
    est = gt.copy()
    est[25:, :3, 3] += [0.0, 0.05, 0.0]  # one jump of 5 cm between frames 24 and 25
    r = rpe(est, gt)
    assert r.trans_errors.max() == pytest.approx(0.05, rel=1e-6) and (r.trans_errors > 1e-9).sum() >= 1
    assert r.trans_errors[np.arange(49) != 24].max() < 0.05


def test_bad_input():
    with pytest.raises(ShapeError, match="estimate has 3 poses"):
        ate(random_trajectory(3), random_trajectory(4))
    bad = random_trajectory(5)
    bad[2, 0, 3] = np.nan
    with pytest.raises(ShapeError, match="non-finite"):
        ate(bad, random_trajectory(5))


def test_tum_trajectory_round_trip(tmp_path):
    poses = random_trajectory(20, seed=13)
    stamps = [1341841873_273798000 + 33_000_000 * i for i in range(20)]
    write_tum_trajectory(tmp_path / "t.txt", stamps, poses)
    s, p = read_tum_trajectory(tmp_path / "t.txt")
    assert s.tolist() == stamps and np.allclose(p, poses, atol=1e-8)
