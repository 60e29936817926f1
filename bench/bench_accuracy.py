"""Accuracy of configuration variants over seeds: ATE, PSNR, depth L1, mIoU and map size, with the seed spread.

Each variant (a name and config overrides) runs the whole SLAM in lockstep once per seed, variants
interleaved per seed. The seed-to-seed standard deviation of each metric is the noise a difference is
judged against: the table gives each variant's mean and standard deviation, and its mean difference
from the first variant with that difference's standard error. Appends the table to BENCHMARKS.md.

    python bench/bench_accuracy.py [INPUT] [--downscale F] [--max-frames N] [--seeds 0 1 ...]
        --variant base --variant clear:densify.front_clearance=2 [--set KEY=VALUE] [--no-append]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import append_section, markdown_table
from sgs_slam_core.cli.demo import default_room_dir, ensure_room
from sgs_slam_core.cli.run import default_preset
from sgs_slam_core.config import SlamConfig, load_config
from sgs_slam_core.datasets import DatasetOptions, open_dataset
from sgs_slam_core.datasets.base import Dataset
from sgs_slam_core.runner import run_offline

# (metrics.json key, column name, scale to the column's unit)
METRICS = (
    ("ate_rmse_m", "ATE cm", 100.0),
    ("psnr_db", "PSNR dB", 1.0),
    ("depth_l1_m", "depth L1 cm", 100.0),
    ("miou", "mIoU %", 100.0),
    ("num_gaussians", "Gaussians", 1.0),
)


@dataclass(frozen=True)
class Variant:
    """A named set of config overrides."""

    name: str
    overrides: tuple[str, ...]

    @staticmethod
    def parse(text: str) -> Variant:
        """``NAME`` or ``NAME:KEY=VALUE,KEY=VALUE``."""
        name, _, rest = text.partition(":")
        return Variant(name, tuple(kv for kv in rest.split(",") if kv))


def run_variant(dataset: Dataset, config: SlamConfig, seed: int) -> dict[str, float | None]:
    """One lockstep run's metrics."""
    out = Path(tempfile.mkdtemp(prefix="bench_accuracy_"))
    cfg = dataclasses.replace(config, seed=seed)
    result = run_offline(dataset, cfg, out, overwrite=True, provenance={"bench": True}, show_progress=False)
    return result.metrics


def summary(values: dict[str, dict[str, list[float]]], names: list[str]) -> str:
    """Per variant and metric: mean +- seed std; beside the first variant's, the difference +- its standard error."""
    rows = []
    base = names[0]
    for name in names:
        row: list[object] = [name]
        for key, _, _ in METRICS:
            v = np.asarray(values[name][key], float)
            if v.size == 0 or np.isnan(v).all():
                row.append("-")
                continue
            cell = f"{np.nanmean(v):.4g} ± {np.nanstd(v, ddof=1) if v.size > 1 else 0:.2g}"
            if name != base:
                b = np.asarray(values[base][key], float)
                diff = v - b if v.size == b.size else None  # paired by seed
                if diff is not None and diff.size > 1:
                    se = np.nanstd(diff, ddof=1) / math.sqrt(diff.size)
                    cell += f" (Δ {np.nanmean(diff):+.3g} ± {se:.2g})"
            row.append(cell)
        rows.append(row)
    return markdown_table(["variant", *(col for _, col, _ in METRICS)], rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("input", nargs="?", type=Path, help="dataset folder or MCAP bag (default: the synthetic room)")
    parser.add_argument("--preset", help="config preset (default: chosen from the dataset)")
    parser.add_argument("--downscale", type=float, help="divide the image size by F (room default: 2 = 160x120)")
    parser.add_argument("--max-frames", type=int)
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1])
    first = "the first is the baseline the others are compared with"
    parser.add_argument(
        "--variant",
        dest="variants",
        action="append",
        type=Variant.parse,
        required=True,
        metavar="NAME[:K=V,...]",
        help=first,
    )
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--no-append", action="store_true")
    args = parser.parse_args()

    data = args.input or ensure_room(default_room_dir())
    downscale = args.downscale or (2.0 if args.input is None else 1.0)
    preset = args.preset or default_preset(data, "auto")
    dataset = open_dataset(data, "auto", DatasetOptions(max_frames=args.max_frames, downscale=downscale))
    configs = {v.name: load_config(preset, None, ["device=cpu", *args.overrides, *v.overrides]) for v in args.variants}
    names = [v.name for v in args.variants]
    values = {name: {key: [] for key, _, _ in METRICS} for name in names}
    for seed in args.seeds:
        for name in names if seed % 2 == 0 else names[::-1]:  # alternate the order: the machine's drift
            m = run_variant(dataset, configs[name], seed)
            for key, _, scale in METRICS:
                values[name][key].append(float("nan") if m.get(key) is None else m[key] * scale)
            shown = {col: round(values[name][key][-1], 3) for key, col, _ in METRICS}
            print(f"{name} seed {seed}: {json.dumps(shown)}", file=sys.stderr, flush=True)
    k = dataset.intrinsics
    variants = "; ".join(f"`{v.name}`: {', '.join(v.overrides) or 'preset'}" for v in args.variants)
    body = (
        f"{dataset.name}, {len(dataset)} frames at {k.width}x{k.height}, preset `{preset}`, lockstep, seeds "
        f"{args.seeds}. Variants: {variants}. Overrides for all: {args.overrides or 'none'}. Mean ± standard "
        f"deviation over seeds; Δ: mean paired difference from `{names[0]}` ± its standard error.\n\n"
        + summary(values, names)
        + "\n"
    )
    print(body)
    if not args.no_append:
        append_section(f"Accuracy: {dataset.name} {k.width}x{k.height}, {preset}, {len(args.seeds)} seeds", body)


if __name__ == "__main__":
    main()
