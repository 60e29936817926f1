"""Are two checkouts' SLAM results identical, bit for bit? (a refactoring's acceptance check)

Runs ``sgs-slam run`` lockstep from each checkout (``PYTHONPATH`` set to it) on the same inputs and
compares what must not change: ``trajectory.txt`` byte for byte and every number in
``metrics.json`` except timings and memory. Inputs, as a refactoring of the SLAM is judged on:

- the tiny synthetic scene, seeds 0-2 (scene and SLAM seed), all 12 frames;
- the synthetic room, first 60 frames, 160x120;
- ``tum_fr3_teddy`` (``--tum``), all frames, 160x120.

Each input runs on the compiled CPU path and on the pure-PyTorch reference path. How a checkout
selects the reference path is a per-side option (an environment variable or config overrides),
since that is what a refactoring may change:

    python bench/bench_identical.py --base /work/base --tum ../shared/data/tum_fr3_teddy

(the defaults: a baseline from before ``render.backend: torch`` meant pure PyTorch selects it with
``SGS_SLAM_NO_CPP=1``, this checkout with ``render.backend=torch``)

Exit status 0 when every pair is identical, 1 otherwise (the differing files are named).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import REPO

# metrics.json keys that measure the machine, not the result
UNTIMED_SKIP = frozenset(
    {"fps", "track_ms_per_frame", "map_ms_per_frame", "load_ms_per_frame", "peak_memory_mb", "lpips_note"}
)


@dataclass(frozen=True)
class Case:
    """One input run: a name, the dataset folder and the run's options."""

    name: str
    data: Path
    args: tuple[str, ...]


@dataclass(frozen=True)
class KernelPath:
    """How one side selects a kernel path: extra environment and config overrides."""

    env: tuple[tuple[str, str], ...] = ()
    sets: tuple[str, ...] = ()


def _pairs(items: list[str] | None) -> tuple[tuple[str, str], ...]:
    out = []
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep:
            raise SystemExit(f"bench_identical: expected NAME=VALUE, got {item!r}")
        out.append((key, value))
    return tuple(out)


def make_inputs(work: Path, tum: Path | None, python: str) -> list[Case]:
    """The synthetic scenes (generated once, by the new checkout) and the TUM sequence."""
    cases = []
    for seed in range(3):
        folder = work / "data" / f"tiny{seed}"
        if not folder.exists():
            cmd = [python, "-m", "sgs_slam_core.cli", "synth", str(folder), "--preset", "tiny", "--seed", str(seed)]
            subprocess.run(cmd, check=True, capture_output=True, env=_env(REPO, ()), cwd=REPO)
        cases.append(Case(f"tiny_seed{seed}", folder, ("--set", f"seed={seed}")))
    room = work / "data" / "room"
    if not room.exists():
        cmd = [python, "-m", "sgs_slam_core.cli", "synth", str(room), "--preset", "room"]
        subprocess.run(cmd, check=True, capture_output=True, env=_env(REPO, ()), cwd=REPO)
    cases.append(Case("room_60", room, ("--downscale", "2", "--max-frames", "60")))
    if tum is not None:
        cases.append(Case("tum_160x120", tum, ("--downscale", "4")))
    return cases


def _env(checkout: Path, extra: tuple[tuple[str, str], ...]) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "SGS_SLAM_NO_CPP"}
    env["PYTHONPATH"] = str(checkout)
    env.update(extra)
    return env


def run_one(python: str, checkout: Path, case: Case, path: KernelPath, out: Path) -> Path:
    """``sgs-slam run`` of ``case`` from ``checkout`` into ``out``; raises with its stderr on failure."""
    cmd = [python, "-m", "sgs_slam_core.cli", "run", str(case.data), "--out", str(out), "--overwrite", "--quiet"]
    cmd += list(case.args)
    for item in path.sets:
        cmd += ["--set", item]
    proc = subprocess.run(cmd, check=False, capture_output=True, text=True, env=_env(checkout, path.env), cwd=checkout)
    if proc.returncode != 0:
        raise RuntimeError(f"{checkout.name} {case.name}: exit {proc.returncode}\n{proc.stderr[-2000:]}")
    return out


def differences(base: Path, new: Path) -> list[str]:
    """What differs between two run folders: trajectory bytes, result metrics."""
    diffs = []
    if (base / "trajectory.txt").read_bytes() != (new / "trajectory.txt").read_bytes():
        diffs.append("trajectory.txt")
    a = json.loads((base / "metrics.json").read_text())
    b = json.loads((new / "metrics.json").read_text())
    for key in sorted(set(a) | set(b)):
        if key in UNTIMED_SKIP:
            continue
        if a.get(key) != b.get(key):
            diffs.append(f"metrics.{key}: {a.get(key)!r} != {b.get(key)!r}")
    return diffs


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--base", type=Path, required=True, help="checkout of the baseline commit")
    parser.add_argument("--new", type=Path, default=REPO, help="checkout to judge (default: this one)")
    parser.add_argument("--tum", type=Path, help="a TUM sequence folder (e.g. ../shared/data/tum_fr3_teddy)")
    parser.add_argument("--work", type=Path, help="folder for inputs and runs (default: a temporary one)")
    parser.add_argument("--only", nargs="*", help="run only these cases (tiny_seed0 ... room_60 tum_160x120)")
    parser.add_argument("--paths", nargs="*", default=["compiled", "reference"], choices=["compiled", "reference"])
    parser.add_argument("--base-reference-env", nargs="*", default=["SGS_SLAM_NO_CPP=1"], metavar="NAME=VALUE")
    parser.add_argument("--base-reference-set", nargs="*", default=[], metavar="KEY=VALUE")
    parser.add_argument("--new-reference-env", nargs="*", default=[], metavar="NAME=VALUE")
    parser.add_argument("--new-reference-set", nargs="*", default=["render.backend=torch"], metavar="KEY=VALUE")
    parser.add_argument("-j", "--jobs", type=int, default=2, help="runs at once (default 2)")
    args = parser.parse_args()

    python = sys.executable
    work = args.work or Path(tempfile.mkdtemp(prefix="identical-"))
    tum = args.tum.resolve() if args.tum else None  # each side runs in its own checkout: a relative path breaks there
    cases = [c for c in make_inputs(work, tum, python) if not args.only or c.name in args.only]
    sides = {
        "compiled": (KernelPath(), KernelPath()),
        "reference": (
            KernelPath(_pairs(args.base_reference_env), tuple(args.base_reference_set)),
            KernelPath(_pairs(args.new_reference_env), tuple(args.new_reference_set)),
        ),
    }
    jobs = []
    for case in cases:
        for kind in args.paths:
            base_path, new_path = sides[kind]
            stem = work / "runs" / f"{case.name}.{kind}"
            jobs.append(
                (case, kind, (args.base, base_path, Path(f"{stem}.base")), (args.new, new_path, Path(f"{stem}.new")))
            )
    with ThreadPoolExecutor(max_workers=args.jobs) as pool:
        futures = {
            (case.name, kind, side): pool.submit(run_one, python, checkout, case, path, out)
            for case, kind, *pair in jobs
            for side, (checkout, path, out) in zip(("base", "new"), pair, strict=True)
        }
        ok = True
        for case, kind, *_ in jobs:
            base_out = futures[(case.name, kind, "base")].result()
            new_out = futures[(case.name, kind, "new")].result()
            diffs = differences(base_out, new_out)
            ok &= not diffs
            print(f"{case.name:14s} {kind:9s} {'identical' if not diffs else 'DIFFERENT: ' + '; '.join(diffs)}")
    print(f"runs in {work}")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
