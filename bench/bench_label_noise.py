"""A map that is right where the segmenter is wrong: label images degraded like a network's, scored against the truth.

Runs ``sgs-slam run --label-noise LEVEL`` on a labelled sequence (default: the built-in synthetic
room) in lockstep and live (``--realtime HZ`` with the labels as a segmenter's late stream), for
each level, and reports the mIoU of the label images fed in and of the map's rendered labels at the
tracked poses, both against the true labels, and the map's gain over its input.

    python bench/bench_label_noise.py [SEQUENCE] [--levels middle] [--realtime 30 --rate-hz 3 --delay-ms 400]
        [--seeds 0] [--set KEY=VALUE ...] [--no-append]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import append_section, cli_metrics, markdown_table
from sgs_slam_core.cli.demo import default_room_dir, ensure_room
from sgs_slam_core.datasets.label_noise import LABEL_NOISE_LEVELS

HEADERS = ["noise", "seed", "run", "tracked", "ATE cm", "input mIoU %", "map mIoU %", "gain (points)", "labels fused"]


def run(source: Path, out: Path, downscale: float, extra: list[str]) -> dict:
    """One ``sgs-slam run``'s metrics.json."""
    return cli_metrics(source, out, ["--downscale", f"{downscale:g}", *extra], "bench_label_noise")


def row(level: str, seed: int, name: str, m: dict) -> list[object]:
    fed, got = m.get("input_miou"), m.get("miou")
    gain = "n/a" if fed is None or got is None else f"{100 * (got - fed):+.1f}"
    return [
        level,
        seed,
        name,
        f"{m['frames_tracked']} / {m['frames_in']}",
        f"{100 * m['ate_rmse_m']:.3f}",
        "n/a" if fed is None else f"{100 * fed:.1f}",
        "n/a" if got is None else f"{100 * got:.1f}",
        gain,
        "every frame's" if m.get("labels_fused") is None else m["labels_fused"],
    ]


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("input", type=Path, nargs="?", help="a labelled sequence (default: the synthetic room)")
    p.add_argument("--downscale", type=float, default=2.0, help="the room is 320x240: 2 gives 160x120")
    p.add_argument("--levels", nargs="+", default=["middle"], choices=list(LABEL_NOISE_LEVELS))
    p.add_argument("--seeds", type=int, nargs="+", default=[0], help="noise seeds (the SLAM's own seed stays)")
    p.add_argument("--realtime", type=float, default=30.0, help="camera rate of the live runs (Hz)")
    p.add_argument("--rate-hz", type=float, default=3.0, help="live: label images a second")
    p.add_argument("--delay-ms", type=float, default=400.0, help="live: each label image this late")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    p.add_argument("--no-append", action="store_true", help="print only; do not append to BENCHMARKS.md")
    args = p.parse_args()
    source = args.input or ensure_room(default_room_dir())
    sets = [a for o in args.overrides for a in ("--set", o)]
    live = ["--realtime", f"{args.realtime:g}", "--label-rate-hz", f"{args.rate_hz:g}"]
    live += ["--label-delay-ms", f"{args.delay_ms:g}"]
    live_name = f"--realtime {args.realtime:g}, labels {args.rate_hz:g} Hz {args.delay_ms:g} ms late"
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for level in args.levels:
            for seed in args.seeds:
                noise = ["--label-noise", level, "--label-noise-seed", str(seed), *sets]
                for name, extra in (("lockstep", noise), (live_name, [*live, *noise])):
                    m = run(source, work / "run", args.downscale, extra)
                    rows.append(row(level, seed, name, m))
                    print(" | ".join(map(str, rows[-1])), flush=True)
    body = markdown_table(HEADERS, rows)
    print(body)
    if not args.no_append:
        append_section(f"Label noise: {source.name}", body)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
