"""Metrics computed as the field defines them, with the SGS-SLAM/SplaTAM variants beside them."""

from sgs_slam_core.metrics.image import depth_l1, ms_ssim, psnr, ssim
from sgs_slam_core.metrics.lpips import load_lpips
from sgs_slam_core.metrics.semantic import ConfusionMatrix, paper_frame_miou
from sgs_slam_core.metrics.trajectory import AteResult, RpeResult, ate, ate_paper, rpe, umeyama
from sgs_slam_core.metrics.trajectory_io import read_tum_trajectory, write_tum_trajectory

__all__ = [
    "AteResult",
    "ConfusionMatrix",
    "RpeResult",
    "ate",
    "ate_paper",
    "depth_l1",
    "load_lpips",
    "ms_ssim",
    "paper_frame_miou",
    "psnr",
    "read_tum_trajectory",
    "rpe",
    "ssim",
    "umeyama",
    "write_tum_trajectory",
]
