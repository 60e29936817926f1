"""``sgs-slam eval``: recompute and print the metrics of a run folder."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from sgs_slam_core.cli.run import open_input
from sgs_slam_core.config import build
from sgs_slam_core.config.loader import known_keys
from sgs_slam_core.config.schema import SlamConfig
from sgs_slam_core.errors import DatasetError
from sgs_slam_core.mapio import load_map
from sgs_slam_core.runner import EvalOptions, evaluate, format_table, read_metrics
from sgs_slam_core.runner.report import write_metrics
from sgs_slam_core.runner.run_info import read_run_info
from sgs_slam_core.semantics import SemanticCodec

__all__ = ["add_parser", "run"]

_KEEP = ("fps", "track_ms_per_frame", "map_ms_per_frame", "load_ms_per_frame", "peak_memory_mb",
         "tracking_failures", "bad_frames", "keyframes", "keyframe_mb", "keyframes_evicted", "gaussian_mb", "device",
         "render_backend", "input_miou")  # fmt: skip


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the sub-command."""
    p = sub.add_parser("eval", help="recompute and print the metrics of a run folder")
    p.add_argument("run_dir", type=Path, help="a folder written by sgs-slam run")
    p.add_argument("--input", type=Path, help="the dataset, if it moved since the run")
    p.add_argument("--no-write", action="store_true", help="print only; leave metrics.json as it is")
    p.set_defaults(func=run)


def _previous_metrics(path: Path) -> dict[str, Any]:
    """The run's own numbers (speed, memory) from an earlier metrics.json; empty if absent or unreadable."""
    try:
        previous = read_metrics(path) if path.is_file() else {}
    except DatasetError as err:
        print(f"warning: {err}; it is replaced", file=sys.stderr)
        return {}
    return previous


def run(args: argparse.Namespace) -> int:
    """Reload dataset, map and trajectory; evaluate; print the table."""
    info = read_run_info(args.run_dir)
    if not (args.run_dir / "map.sgsmap").is_file():
        how = f" (run.yaml: {info.status}{': ' + info.note if info.note else ''})" if info.status else ""
        raise DatasetError(f"{args.run_dir} has no map.sgsmap to evaluate{how}")
    source = args.input or info.input
    if source is None:
        raise DatasetError(f"{args.run_dir / 'run.yaml'} does not name the input; give it with --input")
    dataset = open_input(source, info.format, info.options, info.topics or None)
    saved = load_map(args.run_dir / "map.sgsmap")
    config = build(SlamConfig, known_keys(SlamConfig, saved.config))  # a map of an earlier version too
    frame_ids = [i for i, _, _ in saved.trajectory]  # dataset frame indices
    poses = [p for _, _, p in saved.trajectory]
    if frame_ids and not 0 <= min(frame_ids) <= max(frame_ids) < len(dataset):
        raise DatasetError(
            f"the map's trajectory refers to frame {max(frame_ids)}, but {source} has {len(dataset)} frames "
            "with these options (another input?)"
        )
    codec = SemanticCodec(config.semantic, saved.label_table)
    candidates = saved.seen_labels or saved.label_table.ids
    metrics = evaluate(
        dataset,
        frame_ids,
        poses,
        saved.gaussians,
        codec,
        candidates,
        config.render,
        EvalOptions(config.eval_every, 0, None),
    )
    previous = _previous_metrics(args.run_dir / "metrics.json")
    metrics.update({k: previous[k] for k in _KEEP if k in previous})
    metrics["num_gaussians"] = len(saved.gaussians)
    print(format_table(metrics))
    if not args.no_write:
        write_metrics(args.run_dir / "metrics.json", metrics)
    return 0
