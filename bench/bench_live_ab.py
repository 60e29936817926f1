"""Live (``--realtime``) runs of two checkouts, alternating, on the same input: what a change does live.

A live run tracks what the machine keeps up with, so one run says little and the machine's speed
swings within minutes: the runs alternate base, new, base, new..., so both sides meet the same
spells. Each run is ``sgs-slam run INPUT --realtime [HZ]`` of that checkout in a child process,
evaluated on the trajectory only (``eval_every`` past the end: no renders). Reports every run and
each side's medians, and appends them to BENCHMARKS.md.

    python bench/bench_live_ab.py --base /tmp/base INPUT [--downscale F] [--hz HZ] [--repeats N] [--set K=V]

``--base`` is a checkout of the baseline commit (``git worktree add /tmp/base ce64f7a``); ``--hz``
releases the frames faster than recorded, as a slower machine would meet them.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import REPO, append_section, cli_metrics, markdown_table

HEADERS = ["run", "side", "commit", "tracked", "ATE cm", "tracking ms/frame", "mapping steps/frame", "lost"]
NO_RENDERS = "eval_every=1000000"  # the ATE needs no rendered frame; renders would only cost time


def parse_args() -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("input", type=Path, help="a dataset folder or bag")
    p.add_argument("--base", type=Path, required=True, help="checkout of the baseline commit")
    p.add_argument("--downscale", type=float, default=4.0)
    p.add_argument("--hz", type=float, default=None, help="release rate (default: the recorded stamps)")
    p.add_argument("--repeats", type=int, default=4, help="runs of each side")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="for both sides")
    p.add_argument("--no-append", action="store_true")
    return p.parse_args()


def short_commit(checkout: Path) -> str:
    cmd = ["git", "rev-parse", "--short", "HEAD"]
    return subprocess.run(cmd, cwd=checkout, capture_output=True, text=True, check=True).stdout.strip()


def one_run(args: argparse.Namespace, checkout: Path, out: Path) -> dict:
    """metrics.json of one live run of ``checkout``."""
    realtime = ["--realtime"] if args.hz is None else ["--realtime", f"{args.hz:g}"]
    extra = [f"--set={kv}" for kv in [NO_RENDERS, *args.set]]
    run_args = ["--downscale", f"{args.downscale:g}", *realtime, *extra]
    return cli_metrics(args.input.resolve(), out, run_args, "bench_live_ab", checkout=checkout)


def row(n: int, side: str, commit: str, m: dict) -> list[object]:
    share = m["frames_tracked"] / max(m["frames_in"], 1)
    tracked = f"{m['frames_tracked']} of {m['frames_in']} ({share:.0%})"
    ate = f"{100 * m['ate_rmse_m']:.2f}" if m.get("ate_rmse_m") is not None else "-"
    lost = m.get("tracking_lost_events", "-")
    return [n, side, commit, tracked, ate, f"{m['track_ms_per_frame']:.1f}", f"{m['map_steps_per_frame']:.2f}", lost]


def medians(runs: list[dict]) -> str:
    share = statistics.median(m["frames_tracked"] / max(m["frames_in"], 1) for m in runs)
    ates = [100 * m["ate_rmse_m"] for m in runs if m.get("ate_rmse_m") is not None]
    ate = f"{statistics.median(ates):.2f} cm" if ates else "no ATE"
    return f"{share:.0%} tracked at {ate}"


def main() -> None:
    args = parse_args()
    if args.repeats < 1:
        raise SystemExit("bench_live_ab: --repeats must be >= 1")
    sides = [("base", args.base.resolve()), ("new", REPO)]
    commits = {name: short_commit(checkout) for name, checkout in sides}
    runs: dict[str, list[dict]] = {name: [] for name, _ in sides}
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_live_ab_") as tmp:
        for n in range(1, args.repeats + 1):
            for name, checkout in sides:
                m = one_run(args, checkout, Path(tmp) / name)
                runs[name].append(m)
                rows.append(row(n, name, commits[name], m))
                print(" | ".join(str(v) for v in rows[-1]), flush=True)
    rate = "the recorded stamps" if args.hz is None else f"{args.hz:g} Hz"
    summary = "; ".join(f"{name} ({commits[name]}) {medians(runs[name])}" for name, _ in sides)
    body = (
        f"`{args.input.name}`, frames released at {rate}, downscale {args.downscale:g}, "
        f"overrides {' '.join(args.set) or 'none'}; runs alternate base and new.\n\n"
        f"{markdown_table(HEADERS, rows)}\n\nMedians over {args.repeats} runs each: {summary}.\n"
    )
    print(body)
    if not args.no_append:
        append_section(f"Live A/B: {args.input.name}", body)


if __name__ == "__main__":
    main()
