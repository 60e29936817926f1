"""Labels at their own pace: live semantic mapping with a segmenter's late label stream, against labels on time.

Runs ``sgs-slam run`` on a labelled sequence (default: the built-in synthetic room, generated once):

- **lockstep**, every label with its frame (the reference mIoU);
- **--realtime HZ** with every frame's labels on time;
- **--realtime HZ** with labels as a segmenter gives them (``--label-rate-hz``, ``--label-delay-ms``),
  ``--repeats`` times.

For each: frames tracked, ATE, the map's rendered mIoU (standard and the paper's) at the tracked
poses against the true labels, label images fused and unmatched, and the label latency (a frame's
release to its labels fused, median).

    python bench/bench_late_labels.py [SEQUENCE] [--rate-hz 3 --delay-ms 400 --realtime 30 --repeats 2] [--no-append]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import append_section, cli_metrics, markdown_table
from sgs_slam_core.cli.demo import default_room_dir, ensure_room

HEADERS = ["run", "tracked", "ATE cm", "mIoU %", "mIoU % (paper)", "labels fused", "unmatched", "latency ms"]


def run(source: Path, out: Path, args: argparse.Namespace, extra: list[str]) -> dict:
    """One ``sgs-slam run``'s metrics.json."""
    return cli_metrics(source, out, ["--downscale", str(args.downscale), *extra], "bench_late_labels")


def row(name: str, m: dict) -> list[object]:
    def pct(key: str) -> str:
        return "n/a" if m.get(key) is None else f"{100 * m[key]:.1f}"

    latency = m.get("label_latency_ms")
    return [
        name,
        f"{m['frames_tracked']} / {m['frames_in']}",
        f"{100 * m['ate_rmse_m']:.3f}",
        pct("miou"),
        pct("miou_paper"),
        "every frame's" if m.get("labels_fused") is None else m["labels_fused"],
        "-" if m.get("labels_unmatched") is None else m["labels_unmatched"],
        "-" if latency is None else f"{latency:.0f}",
    ]


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("input", type=Path, nargs="?", help="a labelled sequence (default: the synthetic room)")
    p.add_argument("--downscale", type=float, default=2.0, help="the room is 320x240: 2 gives 160x120")
    p.add_argument("--realtime", type=float, default=30.0, help="camera rate (Hz)")
    p.add_argument("--rate-hz", type=float, default=3.0, help="label images a second")
    p.add_argument("--delay-ms", type=float, default=400.0, help="each label image this late")
    p.add_argument("--repeats", type=int, default=2, help="runs with the late labels")
    p.add_argument("--no-append", action="store_true", help="print only; do not append to BENCHMARKS.md")
    args = p.parse_args()
    source = args.input or ensure_room(default_room_dir())
    live = ["--realtime", f"{args.realtime:g}"]
    late = [*live, "--label-rate-hz", f"{args.rate_hz:g}", "--label-delay-ms", f"{args.delay_ms:g}"]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        rows.append(row("lockstep, labels on time", run(source, work / "lockstep", args, [])))
        rows.append(row(f"--realtime {args.realtime:g}, labels on time", run(source, work / "on_time", args, live)))
        for i in range(args.repeats):
            name = f"--realtime {args.realtime:g}, labels {args.rate_hz:g} Hz {args.delay_ms:g} ms late"
            rows.append(row(name, run(source, work / f"late{i}", args, late)))
    body = markdown_table(HEADERS, rows)
    print(body)
    if not args.no_append:
        append_section(f"Late labels: {source.name}", body)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
