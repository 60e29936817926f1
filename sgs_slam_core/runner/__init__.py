"""Offline runs: drive ``Slam`` over a dataset, write a run folder, evaluate it."""

from sgs_slam_core.runner.evaluation import EvalOptions, evaluate
from sgs_slam_core.runner.offline import RunResult, run_offline
from sgs_slam_core.runner.report import format_table, read_metrics

__all__ = ["EvalOptions", "RunResult", "evaluate", "format_table", "read_metrics", "run_offline"]
