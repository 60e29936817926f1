"""Trajectory metrics: ATE (standard and SplaTAM/SGS-SLAM paper-style) and RPE.

* :func:`ate` - the field's standard: RMSE of camera-centre errors after the closed-form rigid
  (Umeyama/Horn, no scale) alignment of the estimate onto the ground truth, as ``evo_ape -a``.
* :func:`ate_paper` - what SplaTAM-family code reports as "ATE RMSE": poses re-expressed relative to
  their first frame, translation columns of the world-to-camera matrices, rigid alignment, and the
  **mean** (not RMSE) of the errors.
* :func:`rpe` - relative pose error between consecutive frames (no alignment needed).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sgs_slam_core.errors import ShapeError
from sgs_slam_core.geometry.se3 import rotation_angle_deg

__all__ = ["AteResult", "RpeResult", "ate", "ate_paper", "rpe", "umeyama"]


def _check_poses(poses: np.ndarray, name: str) -> np.ndarray:
    poses = np.asarray(poses, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4):
        raise ShapeError(f"{name} must be [N, 4, 4], got {poses.shape}")
    if not np.isfinite(poses).all():
        raise ShapeError(f"{name} contains non-finite poses")
    return poses


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = False) -> tuple[np.ndarray, np.ndarray, float]:
    """``(R [3, 3], t [3], s)`` minimising sum ||s R src_i + t - dst_i||^2 (Umeyama 1991)."""
    src, dst = np.asarray(src, np.float64), np.asarray(dst, np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3:
        raise ShapeError(f"point sets must both be [N, 3], got {src.shape} and {dst.shape}")
    if src.shape[0] < 3:
        raise ShapeError(f"alignment needs at least 3 points, got {src.shape[0]}")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / src.shape[0]
    u, d, vt = np.linalg.svd(cov)
    sign = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sign[2, 2] = -1
    rot = u @ sign @ vt
    scale = float(np.trace(np.diag(d) @ sign) / (xs**2).sum(1).mean()) if with_scale else 1.0
    return rot, mu_d - scale * rot @ mu_s, scale


@dataclass(frozen=True)
class AteResult:
    """Absolute trajectory error statistics (metres) and the alignment used."""

    rmse: float
    mean: float
    median: float
    std: float
    max: float
    errors: np.ndarray  # [N] per-frame error (m)
    rotation: np.ndarray  # [3, 3] applied to the estimate
    translation: np.ndarray  # [3]


def _stats(errors: np.ndarray, rot: np.ndarray, trans: np.ndarray) -> AteResult:
    return AteResult(
        rmse=float(np.sqrt((errors**2).mean())),
        mean=float(errors.mean()),
        median=float(np.median(errors)),
        std=float(errors.std()),
        max=float(errors.max()),
        errors=errors,
        rotation=rot,
        translation=trans,
    )


def ate(est_c2w: np.ndarray, gt_c2w: np.ndarray, align: bool = True) -> AteResult:
    """Standard ATE on camera centres, estimate rigidly aligned onto the ground truth."""
    est, gt = _check_poses(est_c2w, "est_c2w"), _check_poses(gt_c2w, "gt_c2w")
    if est.shape != gt.shape:
        raise ShapeError(f"estimate has {len(est)} poses, ground truth {len(gt)}")
    p_est, p_gt = est[:, :3, 3], gt[:, :3, 3]
    rot, trans = (umeyama(p_est, p_gt)[:2]) if align else (np.eye(3), np.zeros(3))
    errors = np.linalg.norm(p_est @ rot.T + trans - p_gt, axis=1)
    return _stats(errors, rot, trans)


def ate_paper(est_c2w: np.ndarray, gt_c2w: np.ndarray) -> AteResult:
    """SplaTAM/SGS-SLAM evaluation: mean error of aligned w2c translations (frame 0 = identity).

    Its ``mean`` is the number those papers print as "ATE RMSE"; ``rmse`` is given for completeness.
    """
    est, gt = _check_poses(est_c2w, "est_c2w"), _check_poses(gt_c2w, "gt_c2w")
    if est.shape != gt.shape:
        raise ShapeError(f"estimate has {len(est)} poses, ground truth {len(gt)}")
    t_est = np.linalg.inv(np.linalg.inv(est[0]) @ est)[:, :3, 3]
    t_gt = np.linalg.inv(np.linalg.inv(gt[0]) @ gt)[:, :3, 3]
    rot, trans, _ = umeyama(t_est, t_gt)
    return _stats(np.linalg.norm(t_est @ rot.T + trans - t_gt, axis=1), rot, trans)


@dataclass(frozen=True)
class RpeResult:
    """Relative pose error over frame pairs (i, i + delta)."""

    trans_rmse: float  # m
    rot_rmse_deg: float
    trans_errors: np.ndarray  # [N - delta] m
    rot_errors_deg: np.ndarray  # [N - delta]


def rpe(est_c2w: np.ndarray, gt_c2w: np.ndarray, delta: int = 1) -> RpeResult:
    """RPE: error of the relative motion between frames i and i + delta (TUM definition)."""
    est, gt = _check_poses(est_c2w, "est_c2w"), _check_poses(gt_c2w, "gt_c2w")
    if est.shape != gt.shape or len(est) <= delta:
        raise ShapeError(f"need equally long trajectories longer than delta={delta}")
    rel_est = np.linalg.inv(est[:-delta]) @ est[delta:]
    rel_gt = np.linalg.inv(gt[:-delta]) @ gt[delta:]
    err = np.linalg.inv(rel_gt) @ rel_est
    trans = np.linalg.norm(err[:, :3, 3], axis=1)
    rot = rotation_angle_deg(err[:, :3, :3])
    return RpeResult(float(np.sqrt((trans**2).mean())), float(np.sqrt((rot**2).mean())), trans, rot)
