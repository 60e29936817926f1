"""The metrics table printed by ``sgs-slam run`` / ``eval`` and stored as ``metrics.json``."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from sgs_slam_core.errors import DatasetError
from sgs_slam_core.fileio import read_text, write_text

__all__ = ["METRIC_ROWS", "format_table", "read_metrics", "write_metrics"]

# (key, label, unit conversion, format)
METRIC_ROWS: tuple[tuple[str, str, float, str], ...] = (
    ("frames", "frames", 1, "{:.0f}"),
    ("frames_dropped", "frames dropped (realtime: tracker busy)", 1, "{:.0f}"),
    ("realtime_hz", "realtime replay rate (Hz)", 1, "{:.1f}"),
    ("labels_fused", "label images fused (realtime: late labels)", 1, "{:.0f}"),
    ("labels_unmatched", "label images unmatched", 1, "{:.0f}"),
    ("label_latency_ms", "label latency (ms, frame -> labels fused)", 1, "{:.0f}"),
    ("ate_rmse_m", "ATE RMSE (cm, aligned camera centres)", 100, "{:.3f}"),
    ("ate_mean_m", "ATE mean (cm)", 100, "{:.3f}"),
    ("ate_paper_m", "ATE as SplaTAM/SGS-SLAM print it (cm)", 100, "{:.3f}"),
    ("rpe_trans_m", "RPE translation RMSE (cm/frame)", 100, "{:.3f}"),
    ("rpe_rot_deg", "RPE rotation RMSE (deg/frame)", 1, "{:.3f}"),
    ("psnr_db", "PSNR (dB)", 1, "{:.2f}"),
    ("psnr_masked_db", "PSNR, valid-depth mask (dB, paper protocol)", 1, "{:.2f}"),
    ("ssim", "SSIM", 1, "{:.4f}"),
    ("ms_ssim", "MS-SSIM (paper's 'SSIM')", 1, "{:.4f}"),
    ("lpips", "LPIPS", 1, "{:.4f}"),
    ("depth_l1_m", "depth L1 (cm)", 100, "{:.3f}"),
    ("miou", "mIoU (standard)", 100, "{:.2f}"),
    ("miou_paper", "mIoU (SGS-SLAM protocol)", 100, "{:.2f}"),
    ("pixel_accuracy", "semantic pixel accuracy (%)", 100, "{:.2f}"),
    ("input_miou", "mIoU of the label images fed in (--label-noise)", 100, "{:.2f}"),
    ("fps", "FPS (tracking + mapping)", 1, "{:.3f}"),
    ("track_ms_per_frame", "tracking (ms/frame)", 1, "{:.0f}"),
    ("map_ms_per_frame", "mapping (ms/frame)", 1, "{:.0f}"),
    ("num_gaussians", "Gaussians", 1, "{:,.0f}"),
    ("gaussian_mb", "Gaussian tensors (MB)", 1, "{:.1f}"),
    ("keyframes", "keyframes held", 1, "{:.0f}"),
    ("keyframe_mb", "keyframe images held (MB)", 1, "{:.1f}"),
    ("peak_memory_mb", "peak memory (MB)", 1, "{:.0f}"),
    ("tracking_failures", "tracking failures", 1, "{:.0f}"),
    ("tracking_lost_events", "times lost", 1, "{:.0f}"),
    ("relocalizations", "relocalizations", 1, "{:.0f}"),
    ("frames_while_lost", "frames while lost", 1, "{:.0f}"),
)


def _fmt(value: Any, scale: float, fmt: str) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "n/a"
    return fmt.format(value * scale)


def format_table(metrics: dict[str, Any]) -> str:
    """A two-column text table of the run's metrics (n/a where not applicable)."""
    rows = [(label, _fmt(metrics.get(key), scale, fmt)) for key, label, scale, fmt in METRIC_ROWS]
    width = max(len(label) for label, _ in rows)
    lines = [f"{label.ljust(width)}  {value}" for label, value in rows]
    if metrics.get("lpips") is None and metrics.get("lpips_note"):
        lines.append(f"(LPIPS not computed: {metrics['lpips_note']})")
    return "\n".join(lines)


def _clean(value: Any) -> Any:
    if isinstance(value, float) and (math.isnan(value) or math.isinf(value)):
        return None
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    return value


def write_metrics(path: Path, metrics: dict[str, Any]) -> None:
    """JSON with NaN/inf as null, written atomically."""
    write_text(path, json.dumps(_clean(metrics), indent=2, sort_keys=False) + "\n")


def read_metrics(path: Path) -> dict[str, Any]:
    """Load a ``metrics.json`` (a JSON object; anything else raises :class:`DatasetError`)."""
    try:
        metrics = json.loads(read_text(path, "metrics file"))
    except json.JSONDecodeError as err:
        raise DatasetError(f"cannot read metrics {path}: {err}") from err
    if not isinstance(metrics, dict):
        raise DatasetError(f"metrics file {path}: expected a JSON object, got {type(metrics).__name__}")
    return metrics
