"""``sgs-slam eval``: recompute and print the metrics of a run folder."""

from __future__ import annotations

import argparse
from pathlib import Path

import yaml

from sgs_slam_core.cli.run import open_input
from sgs_slam_core.config import build
from sgs_slam_core.config.schema import SlamConfig
from sgs_slam_core.datasets import DatasetOptions
from sgs_slam_core.errors import DatasetError
from sgs_slam_core.mapio import load_map
from sgs_slam_core.runner import EvalOptions, evaluate, format_table, read_metrics
from sgs_slam_core.runner.report import write_metrics
from sgs_slam_core.semantics import SemanticCodec

__all__ = ["add_parser", "run"]

_KEEP = ("fps", "track_ms_per_frame", "map_ms_per_frame", "load_ms_per_frame", "peak_memory_mb",
         "tracking_failures", "bad_frames", "keyframes", "device", "render_backend")  # fmt: skip


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the sub-command."""
    p = sub.add_parser("eval", help="recompute and print the metrics of a run folder")
    p.add_argument("run_dir", type=Path, help="a folder written by sgs-slam run")
    p.add_argument("--input", type=Path, help="the dataset, if it moved since the run")
    p.add_argument("--no-write", action="store_true", help="print only; leave metrics.json as it is")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Reload dataset, map and trajectory; evaluate; print the table."""
    run_yaml = args.run_dir / "run.yaml"
    if not run_yaml.is_file():
        raise DatasetError(f"{args.run_dir} is not a run folder (no run.yaml)")
    info = yaml.safe_load(run_yaml.read_text()) or {}
    source = args.input or Path(info.get("input", ""))
    options = DatasetOptions(**info.get("options", {}))
    dataset = open_input(source, info.get("format", "auto"), options, info.get("topics") or None)
    saved = load_map(args.run_dir / "map.sgsmap")
    config = build(SlamConfig, saved.config)
    frame_ids = [i for i, _, _ in saved.trajectory]  # dataset frame indices
    poses = [p for _, _, p in saved.trajectory]
    codec = SemanticCodec(config.semantic, saved.label_table)
    candidates = saved.seen_labels or saved.label_table.ids
    metrics = evaluate(dataset, frame_ids, poses, saved.gaussians, codec, candidates, config.render,
                       EvalOptions(config.eval_every, 0, None))  # fmt: skip
    previous = read_metrics(args.run_dir / "metrics.json") if (args.run_dir / "metrics.json").is_file() else {}
    metrics.update({k: previous[k] for k in _KEEP if k in previous})
    metrics["num_gaussians"] = len(saved.gaussians)
    print(format_table(metrics))
    if not args.no_write:
        write_metrics(args.run_dir / "metrics.json", metrics)
    return 0
