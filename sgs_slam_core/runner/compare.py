"""One table across run folders (as ``evo_res`` does for trajectories): metrics side by side.

Rows are runs, columns are metrics in display units (cm, dB, %) plus the run's dataset, preset,
source commit and device from ``run.yaml``. The best value of each metric column is marked.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from sgs_slam_core.errors import DatasetError
from sgs_slam_core.fileio import read_yaml
from sgs_slam_core.runner.report import METRIC_ROWS, read_metrics

__all__ = ["DEFAULT_METRICS", "RunSummary", "TableFormat", "format_comparison", "load_run", "metric_keys"]

TableFormat = Literal["text", "markdown", "csv"]

DEFAULT_METRICS = ("frames", "ate_rmse_m", "rpe_trans_m", "psnr_db", "ssim", "lpips", "depth_l1_m", "miou", "fps",
                   "num_gaussians")  # fmt: skip
_SHORT = {
    "frames": "frames", "ate_rmse_m": "ATE RMSE cm", "ate_mean_m": "ATE mean cm", "ate_paper_m": "ATE (paper) cm",
    "rpe_trans_m": "RPE cm/f", "rpe_rot_deg": "RPE deg/f", "psnr_db": "PSNR dB", "psnr_masked_db": "PSNR (mask) dB",
    "ssim": "SSIM", "ms_ssim": "MS-SSIM", "lpips": "LPIPS", "depth_l1_m": "depth L1 cm", "miou": "mIoU %",
    "miou_paper": "mIoU (paper) %", "pixel_accuracy": "pixel acc. %", "fps": "FPS",
    "track_ms_per_frame": "track ms", "map_ms_per_frame": "map ms", "num_gaussians": "Gaussians",
    "peak_memory_mb": "peak MB", "tracking_failures": "failures",
}  # fmt: skip
_HIGHER_IS_BETTER = {"psnr_db", "psnr_masked_db", "ssim", "ms_ssim", "miou", "miou_paper", "pixel_accuracy", "fps"}
_NEUTRAL = {"frames", "num_gaussians"}  # no "best"
_ROWS = {key: (scale, fmt) for key, _, scale, fmt in METRIC_ROWS}
_INFO_COLUMNS = ("dataset", "preset", "commit", "device")


def metric_keys() -> list[str]:
    """Metric names ``--metrics`` accepts (the keys of ``metrics.json`` in the run table)."""
    return [key for key, *_ in METRIC_ROWS]


@dataclass(frozen=True)
class RunSummary:
    """A run folder's metrics and where they came from."""

    name: str
    metrics: dict[str, Any]
    info: dict[str, str]  # dataset, preset, commit, device


def _info(run_yaml: dict[str, Any], metrics: dict[str, Any]) -> dict[str, str]:
    git = run_yaml.get("git") or {}
    commit = str(git.get("commit", ""))[:8] + ("+dirty" if git.get("dirty") else "") if git else "-"
    device = run_yaml.get("device")
    if isinstance(device, dict):
        device_name = f"{device.get('type', '')}: {device.get('name', '')}".strip(": ")
    else:
        device_name = str(metrics.get("device", "-"))
    dataset = Path(str(run_yaml.get("input", ""))).name or "-"
    return {
        "dataset": dataset,
        "preset": str(run_yaml.get("preset") or "-"),
        "commit": commit or "-",
        "device": device_name or "-",
    }


def load_run(path: Path, name: str | None = None) -> RunSummary:
    """Read ``metrics.json`` and ``run.yaml`` of a run folder (run.yaml may be missing)."""
    if not (path / "metrics.json").is_file():
        raise DatasetError(f"{path} is not a run folder (no metrics.json)")
    metrics = read_metrics(path / "metrics.json")
    run_yaml: dict[str, Any] = {}
    if (path / "run.yaml").is_file():
        run_yaml = read_yaml(path / "run.yaml", "run file") or {}
        if not isinstance(run_yaml, dict):
            raise DatasetError(f"{path / 'run.yaml'}: expected a mapping, got {type(run_yaml).__name__}")
    return RunSummary(name or str(path), metrics, _info(run_yaml, metrics))


def _value(metrics: dict[str, Any], key: str) -> float | None:
    v = metrics.get(key)
    if isinstance(v, bool) or not isinstance(v, int | float) or math.isnan(v) or math.isinf(v):
        return None
    return float(v) * _ROWS[key][0]


def _best(runs: Sequence[RunSummary], key: str) -> float | None:
    values = [v for r in runs if (v := _value(r.metrics, key)) is not None]
    if key in _NEUTRAL or len(values) < 2:
        return None
    return max(values) if key in _HIGHER_IS_BETTER else min(values)


def format_comparison(
    runs: Sequence[RunSummary], keys: Sequence[str] = DEFAULT_METRICS, fmt: TableFormat = "text", info: bool = True
) -> str:
    """The table: one row per run; the best value of each metric marked (``*`` text, bold markdown)."""
    unknown = [k for k in keys if k not in _ROWS]
    if unknown:
        raise DatasetError(f"unknown metric {', '.join(unknown)}; known: {', '.join(metric_keys())}")
    header = ["run", *(_SHORT.get(k, k) for k in keys), *(_INFO_COLUMNS if info else ())]
    best = {k: _best(runs, k) for k in keys}
    rows: list[list[str]] = []
    for run in runs:
        cells = [run.name]
        for k in keys:
            v = _value(run.metrics, k)
            if fmt == "csv":
                cells.append("" if v is None else repr(v))
                continue
            text = "n/a" if v is None else _ROWS[k][1].format(v)
            if v is not None and best[k] is not None and math.isclose(v, best[k]):  # type: ignore[arg-type]
                text = f"**{text}**" if fmt == "markdown" else f"{text}*"
            cells.append(text)
        cells += [run.info[c] for c in _INFO_COLUMNS] if info else []
        rows.append(cells)
    if fmt == "csv":
        buf = io.StringIO()
        csv.writer(buf, lineterminator="\n").writerows([header, *rows])
        return buf.getvalue().rstrip("\n")
    if fmt == "markdown":
        lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
        return "\n".join([*lines, *("| " + " | ".join(r) + " |" for r in rows)])
    widths = [max(len(row[i]) for row in [header, *rows]) for i in range(len(header))]
    numeric = [False, *(True for _ in keys), *(False for _ in (_INFO_COLUMNS if info else ()))]

    def line(cells: list[str]) -> str:
        return "  ".join(c.rjust(w) if num else c.ljust(w) for c, w, num in zip(cells, widths, numeric, strict=True))

    out = [line(header), "  ".join("-" * w for w in widths), *(line(r) for r in rows)]
    if any(b is not None for b in best.values()):
        out.append("(* best in its column)")
    return "\n".join(s.rstrip() for s in out)
