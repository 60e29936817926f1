"""Evaluation of a finished run: trajectory metrics, image metrics, mIoU, renders and plots.

Images are rendered with the final map at the final estimated poses (the reference's protocol) on
frame 0 and every frame with (t + 1) % eval_every == 0.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from sgs_slam_core.datasets.base import Dataset
from sgs_slam_core.fileio import make_dir
from sgs_slam_core.frame import Frame
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.kernels import render
from sgs_slam_core.metrics import (
    ConfusionMatrix,
    ate,
    ate_paper,
    depth_l1,
    load_lpips,
    ms_ssim,
    paper_frame_miou,
    psnr,
    rpe,
    ssim,
)
from sgs_slam_core.render.output import RenderOutput
from sgs_slam_core.render.settings import RenderSettings
from sgs_slam_core.semantics import SemanticCodec
from sgs_slam_core.viz import RenderPanel, plot_trajectory, save_render_panels

__all__ = ["EvalOptions", "eval_indices", "evaluate", "input_miou", "trajectory_metrics"]


@dataclass(frozen=True)
class EvalOptions:
    """What to evaluate and where to put pictures."""

    eval_every: int = 5
    render_examples: int = 4  # frames saved side by side with ground truth under renders/
    out_dir: Path | None = None


def eval_indices(n: int, every: int) -> list[int]:
    """Frame 0 and every frame t with (t + 1) % every == 0."""
    return [t for t in range(n) if t == 0 or (t + 1) % every == 0]


def trajectory_metrics(est: np.ndarray, gt: np.ndarray) -> dict[str, float | None]:
    """ATE (standard and paper-style) and RPE over frames with ground truth."""
    if len(est) < 3:
        return {"ate_rmse_m": None, "ate_mean_m": None, "ate_paper_m": None, "rpe_trans_m": None, "rpe_rot_deg": None}
    standard, paper, relative = ate(est, gt), ate_paper(est, gt), rpe(est, gt)
    return {
        "ate_rmse_m": standard.rmse,
        "ate_mean_m": standard.mean,
        "ate_paper_m": paper.mean,
        "rpe_trans_m": relative.trans_rmse,
        "rpe_rot_deg": relative.rot_rmse_deg,
    }


class _FrameMetrics:
    """Accumulates per-frame image metrics and the semantic confusion matrix."""

    def __init__(self, codec: SemanticCodec, candidates: list[int], device: torch.device) -> None:
        self.codec, self.candidates = codec, candidates
        self.lpips, self.lpips_note = load_lpips(device)
        self.cm = ConfusionMatrix()
        self.values: dict[str, list[float]] = {
            k: [] for k in ("psnr", "psnr_masked", "ssim", "ms_ssim", "depth_l1", "lpips", "miou_paper")
        }

    def add(self, frame: Frame, out: RenderOutput) -> np.ndarray | None:
        """Score one frame; returns the decoded class ids [H, W] when the frame is labelled."""
        device = out.color.device
        gt_rgb = torch.from_numpy(frame.rgb).to(device).float() / 255
        gt_depth = torch.from_numpy(frame.depth).to(device)
        pred = out.color.clamp(0, 1)
        mask = (gt_depth > 0)[..., None].float()
        v = self.values
        v["psnr"].append(psnr(pred, gt_rgb))
        v["psnr_masked"].append(psnr(pred * mask, gt_rgb * mask))  # SplaTAM: zero invalid pixels in both
        v["ssim"].append(float(ssim(pred, gt_rgb)))
        v["ms_ssim"].append(ms_ssim(pred, gt_rgb))
        v["depth_l1"].append(depth_l1(out.depth, gt_depth))
        if self.lpips is not None:
            v["lpips"].append(float(self.lpips(pred, gt_rgb)))
        if frame.labels is None:
            return None
        labels = torch.from_numpy(frame.labels.astype(np.int64))
        decoded = self.codec.decode_image(out.semantic, self.candidates).cpu()
        self.cm.update(decoded, labels)
        present = sorted(int(i) for i in np.unique(frame.labels))
        v["miou_paper"].append(paper_frame_miou(self.codec.decode(out.semantic, present).cpu(), labels))
        return decoded.numpy()

    def summary(self) -> dict[str, Any]:
        """Means over frames (None where nothing was measured)."""

        def mean(key: str) -> float | None:
            vals = [x for x in self.values[key] if np.isfinite(x)]
            return float(np.mean(vals)) if vals else None

        labelled = self.cm.total > 0
        return {
            "psnr_db": mean("psnr"),
            "psnr_masked_db": mean("psnr_masked"),
            "ssim": mean("ssim"),
            "ms_ssim": mean("ms_ssim"),
            "depth_l1_m": mean("depth_l1"),
            "lpips": mean("lpips"),
            "lpips_note": self.lpips_note or None,
            "miou": self.cm.miou() if labelled else None,
            "miou_paper": mean("miou_paper"),
            "pixel_accuracy": self.cm.pixel_accuracy() if labelled else None,
            "per_class_iou": {self.codec.table.name_of(c): x for c, x in self.cm.iou().items()},
        }


def _plot(
    path: Path, poses: list[np.ndarray], est: np.ndarray, gt: np.ndarray, gt_stamps: np.ndarray, ate_rmse: float | None
) -> None:
    """Trajectory plot; with ground truth the estimate is first aligned onto it."""
    if len(est) >= 3:
        res = ate(est, gt)
        aligned = est.copy()
        aligned[:, :3, :3] = res.rotation @ est[:, :3, :3]
        aligned[:, :3, 3] = est[:, :3, 3] @ res.rotation.T + res.translation
        title = f"estimate (aligned) vs ground truth: ATE RMSE {100 * (ate_rmse or 0):.2f} cm over {len(est)} frames"
        plot_trajectory(path, aligned, gt, gt_stamps, title=title)
    else:
        plot_trajectory(
            path, np.stack(poses), None, title=f"estimated trajectory, {len(poses)} frames (no ground truth)"
        )


def input_miou(fed: Dataset, truth: Dataset, every: int) -> float | None:
    """The mIoU of ``fed``'s label images against ``truth``'s, over frame 0 and every ``every``-th frame that has one.

    Every run of a sequence scores the same frames, whichever it tracked. None without labels.
    """
    scores = ConfusionMatrix()
    for i in eval_indices(len(truth), every):
        fed_labels = fed[i].labels
        if fed_labels is not None:
            true_labels = truth[i].labels
            if true_labels is not None:
                scores.update(fed_labels, true_labels)
    return scores.miou() if scores.total > 0 else None


def evaluate(
    dataset: Dataset,
    frame_indices: list[int],  # dataset index of every processed frame, in order
    poses: list[np.ndarray],  # estimated c2w of every processed frame
    gaussians: GaussianMap,
    codec: SemanticCodec,
    candidates: list[int],
    render_settings: RenderSettings,
    options: EvalOptions,
    progress: Callable[[int, int], None] | None = None,
    fed: Dataset | None = None,
) -> dict[str, Any]:
    """Compute every metric of ``metrics.json`` that depends on the map and trajectory.

    ``dataset`` holds the truth the map is scored against. ``fed``: the same frames as they went in
    when their labels were not the truth (``--label-noise``); their label images are scored against
    the truth too (``input_miou``, :func:`input_miou`).
    """
    with_gt = []  # (estimate, ground truth, stamp_ns) of frames with ground truth
    stamps = dataset.stamps_ns
    for i, p in zip(frame_indices, poses, strict=True):
        gt_c2w = dataset.ground_truth(i)  # no image decoded: only the evaluated frames below are read
        if gt_c2w is not None:
            with_gt.append((p, gt_c2w, stamps[i]))
    est = np.stack([p for p, _, _ in with_gt]) if with_gt else np.zeros((0, 4, 4))
    gt = np.stack([g for _, g, _ in with_gt]) if with_gt else np.zeros((0, 4, 4))
    gt_stamps = np.array([s for _, _, s in with_gt], dtype=np.int64)
    metrics: dict[str, Any] = {"frames": len(frame_indices), **trajectory_metrics(est, gt), "gt_frames": len(with_gt)}

    scores = _FrameMetrics(codec, candidates, gaussians.device)
    chosen = eval_indices(len(frame_indices), options.eval_every)
    examples = set(chosen[:: max(1, len(chosen) // max(options.render_examples, 1))][: options.render_examples])
    if options.out_dir is not None and examples:
        make_dir(options.out_dir / "renders")
    for n, t in enumerate(chosen):
        frame = dataset[frame_indices[t]]
        w2c = torch.as_tensor(np.linalg.inv(poses[t]), dtype=torch.float32, device=gaussians.device)
        with torch.no_grad():
            out = render(gaussians, frame.intrinsics, w2c, render_settings, with_semantics=frame.labels is not None)
        pred_labels = scores.add(frame, out)
        if t in examples and options.out_dir is not None:
            path = options.out_dir / "renders" / f"frame_{frame_indices[t]:06d}.png"
            panel = RenderPanel(
                frame.rgb,
                out.color.cpu().numpy(),
                frame.depth,
                out.depth.cpu().numpy(),
                frame.labels if pred_labels is not None else None,
                pred_labels,
            )
            title = f"frame {frame_indices[t]} (dataset index), rendered from the final map at the estimated pose"
            save_render_panels(path, panel, codec.table, title)
        if progress:
            progress(n + 1, len(chosen))
    metrics.update(scores.summary(), eval_frames=len(chosen))
    if fed is not None:
        metrics["input_miou"] = input_miou(fed, dataset, options.eval_every)
    if options.out_dir is not None and len(poses) >= 2:
        _plot(options.out_dir / "trajectory.png", poses, est, gt, gt_stamps, metrics["ate_rmse_m"])
    return metrics
