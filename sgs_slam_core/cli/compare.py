"""``sgs-slam compare RUN...``: one table of metrics across run folders (like ``evo_res``)."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from sgs_slam_core.errors import DatasetError
from sgs_slam_core.fileio import write_text
from sgs_slam_core.runner.compare import DEFAULT_METRICS, RunSummary, format_comparison, load_run, metric_keys

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the sub-command."""
    p = sub.add_parser(
        "compare",
        help="print one table of metrics across run folders",
        description="Rows are runs, columns metrics (cm, dB, %%) plus dataset, preset, commit and device from "
        "run.yaml; the best value of each metric is marked.",
    )
    p.add_argument("runs", type=Path, nargs="+", metavar="RUN", help="run folders written by sgs-slam run")
    p.add_argument(
        "--metrics",
        default=",".join(DEFAULT_METRICS),
        metavar="KEY,...",
        help=f"metrics.json keys to show (default: {','.join(DEFAULT_METRICS)}; all: {','.join(metric_keys())})",
    )
    p.add_argument("--sort", metavar="KEY", help="sort rows by this metric (ascending; runs without it last)")
    p.add_argument("--descending", action="store_true", help="sort from the largest value")
    p.add_argument("--format", dest="fmt", choices=["text", "markdown", "csv"], default="text", help="table format")
    p.add_argument("--no-info", action="store_true", help="leave out dataset, preset, commit and device")
    p.add_argument("--out", type=Path, help="also write the table to this file")
    p.set_defaults(func=run)


def _names(paths: list[Path]) -> list[str]:
    """Shortest distinguishing names: the paths relative to their common parent."""
    resolved = [p.resolve() for p in paths]
    if len(resolved) == 1:
        return [paths[0].name or str(paths[0])]
    common = Path(os.path.commonpath(resolved))
    return [str(p.relative_to(common)) if p != common else p.name for p in resolved]


def run(args: argparse.Namespace) -> int:
    """Load every run, sort, print (and write) the table."""
    keys = [k.strip() for k in args.metrics.split(",") if k.strip()]
    runs = [load_run(path, name) for path, name in zip(args.runs, _names(args.runs), strict=True)]
    if args.sort is not None:
        if args.sort not in metric_keys():
            raise DatasetError(f"--sort {args.sort!r}: unknown metric; known: {', '.join(metric_keys())}")

        def sort_key(r: RunSummary) -> tuple[bool, float]:
            v = r.metrics.get(args.sort)
            missing = not isinstance(v, int | float)
            value = 0.0 if missing else float(v)
            return (missing, -value if args.descending else value)

        runs.sort(key=sort_key)
    table = format_comparison(runs, keys, args.fmt, info=not args.no_info)
    print(table)
    if args.out is not None:
        write_text(args.out, table + "\n")
    return 0
