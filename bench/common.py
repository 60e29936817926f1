"""Shared helpers for benchmarks: machine description, commit, BENCHMARKS.md appends."""

from __future__ import annotations

import contextlib
import datetime as dt
import json
import multiprocessing
import os
import platform
import shlex
import subprocess
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import torch

from sgs_slam_core.synthetic import SynthConfig, generate

REPO = Path(__file__).resolve().parents[1]
BENCHMARKS_MD = REPO / "BENCHMARKS.md"


def machine() -> str:
    """CPU model, core count and torch build, plus the GPU when one is used."""
    cpu = platform.processor() or "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    text = f"{cpu}, {os.cpu_count()} cores, torch {torch.__version__} ({torch.get_num_threads()} threads)"
    if torch.cuda.is_available():
        text += f", GPU {torch.cuda.get_device_name(0)}"
    return text


def commit() -> str:
    """Short commit id, with '+dirty' when the tree has uncommitted changes."""
    try:
        rev = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True, text=True, check=True
        )
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=REPO,
            capture_output=True,
            text=True,
            check=True,
        )
        return rev.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def command_line() -> str:
    """The command that ran this benchmark, relative to the repository."""
    script = Path(sys.argv[0]).resolve()
    with contextlib.suppress(ValueError):
        script = script.relative_to(REPO)
    return shlex.join(["python", str(script), *sys.argv[1:]])


def markdown_table(headers: list[str], rows: list[list[object]]) -> str:
    """A GitHub-flavoured markdown table."""
    lines = ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
    lines += ["| " + " | ".join(str(v) for v in row) + " |" for row in rows]
    return "\n".join(lines)


def append_section(title: str, body: str) -> None:
    """Append a dated section with machine, commit and command to BENCHMARKS.md (or ``$SGS_SLAM_BENCH_OUT``)."""
    stamp = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    header = (
        f"\n## {title}\n\n- date: {stamp}\n- machine: {machine()}\n- commit: {commit()}\n"
        f"- command: `{command_line()}`\n\n"
    )
    target = Path(os.environ.get("SGS_SLAM_BENCH_OUT") or BENCHMARKS_MD)  # the GPU suite collects them under $OUT
    if not target.exists():
        target.write_text("# Benchmarks\n\nEvery section is appended by a script in `bench/`.\n")
    with target.open("a") as f:
        f.write(header + body.rstrip() + "\n")


def generate_apart(path: Path, config: SynthConfig) -> Path:
    """``synthetic.generate`` in a child process: a memory benchmark measures the SLAM, not the scene
    rendering (its arrays would stay in this process's heap)."""
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=1, mp_context=ctx) as pool:
        return pool.submit(generate, path, config).result()


def cli_metrics(source: Path, out: Path, args: list[str], bench: str, checkout: Path = REPO) -> dict:
    """``sgs-slam run SOURCE --out OUT ARGS`` of ``checkout`` in a child process; its metrics.json.

    Failing, the bench exits naming ``bench``.
    """
    cmd = [sys.executable, "-m", "sgs_slam_core.cli", "run", str(source), "--out", str(out), "--overwrite", "--quiet"]
    proc = subprocess.run([*cmd, *args], check=False, capture_output=True, text=True, cwd=checkout)
    if proc.returncode != 0:
        raise SystemExit(f"{bench}: {' '.join([*cmd, *args])} failed:\n{proc.stderr[-2000:]}")
    return json.loads((out / "metrics.json").read_text())
