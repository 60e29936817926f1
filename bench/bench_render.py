"""Renderer benchmark: forward + backward time, memory and throughput per backend.

Scene: N isotropic Gaussians uniform in a 3 x 2.2 x 1.5 m
box 2-3.5 m in front of the camera, radii 2-6 cm, random opacities, 3 colour + 3 semantic channels,
fx = fy = 0.9 W. Loss over every channel; gradients to all Gaussian parameters and the pose.

    python bench/bench_render.py [--backend torch|gsplat|all] [--repeats 7] [--no-append]
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import append_section, markdown_table
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.geometry import Intrinsics, se3_exp
from sgs_slam_core.kernels import gsplat as gsplat_backend
from sgs_slam_core.kernels import render
from sgs_slam_core.kernels.cpu.extensions import RENDER
from sgs_slam_core.render import RenderSettings

CPU_CASES = [(80, 60, 2_000), (160, 120, 5_000), (320, 240, 20_000)]
GPU_CASES = [*CPU_CASES, (640, 480, 100_000), (1200, 680, 300_000)]


def scene(n: int, width: int, height: int, device: str) -> tuple[GaussianMap, Intrinsics]:
    g = torch.Generator().manual_seed(0)
    means = torch.rand(n, 3, generator=g) * torch.tensor([3.0, 2.2, 1.5]) + torch.tensor([-1.5, -1.1, 2.0])
    gm = GaussianMap(
        means=means,
        log_scales=(0.02 + 0.04 * torch.rand(n, 1, generator=g)).log(),
        logit_opacities=torch.randn(n, generator=g),
        colors=torch.rand(n, 3, generator=g),
        semantics=torch.rand(n, 3, generator=g),
        labels=torch.zeros(n, dtype=torch.long),
        birth_frame=torch.zeros(n, dtype=torch.long),
    )
    return gm.to(device), Intrinsics(0.9 * width, 0.9 * width, (width - 1) / 2, (height - 1) / 2, width, height)


def run_case(width: int, height: int, n: int, backend: str, device: str, repeats: int) -> dict[str, float]:
    gm, k = scene(n, width, height, device)
    settings = RenderSettings(backend=backend)  # type: ignore[arg-type]
    params = {f: getattr(gm, f).clone().requires_grad_(True) for f in GaussianMap.optimised_fields(False)}
    xi = torch.zeros(6, device=device, requires_grad=True)
    sync = torch.cuda.synchronize if device == "cuda" else (lambda: None)
    times = []
    for i in range(repeats + 2):  # two warm-up iterations
        sync()
        t0 = time.perf_counter()
        out = render(gm.with_tensors(**params), k, se3_exp(xi), settings)
        loss = out.color.sum() + out.depth.sum() + out.silhouette.sum() + out.semantic.sum()
        loss.backward()
        sync()
        if i >= 2:
            times.append(time.perf_counter() - t0)
    median = statistics.median(times)
    peak = (
        torch.cuda.max_memory_allocated() / 2**20
        if device == "cuda"
        else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    )
    return {"median_s": median, "min_s": min(times), "peak_mb": peak, "gpix_per_s": n * width * height / median / 1e9}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--backend", choices=["torch", "cpu", "gsplat", "all"], default="all")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--no-append", action="store_true", help="print only, do not append to BENCHMARKS.md")
    parser.add_argument("--case", help=argparse.SUPPRESS)  # internal: run one case in this process
    args = parser.parse_args()
    if args.case:
        w, h, n, backend, device = args.case.split(",")
        print(json.dumps(run_case(int(w), int(h), int(n), backend, device, args.repeats)))
        return

    cuda = torch.cuda.is_available()
    backends = ["torch", "cpu", "gsplat"] if args.backend == "all" else [args.backend]
    if "gsplat" in backends and not (cuda and gsplat_backend.is_available()):
        print(f"gsplat skipped: {'no CUDA device' if not cuda else gsplat_backend.import_error()}")
        backends.remove("gsplat")
    if "cpu" in backends and not RENDER.is_available():
        print(f"cpu skipped: {RENDER.unavailable_reason()}")
        backends.remove("cpu")
    rows = []
    for backend in backends:
        device = "cuda" if backend == "gsplat" or (backend == "torch" and cuda) else "cpu"
        for w, h, n in GPU_CASES if device == "cuda" or backend == "cpu" else CPU_CASES:
            # One process per case, so peak memory is that case's own.
            cmd = [
                sys.executable,
                __file__,
                "--case",
                f"{w},{h},{n},{backend},{device}",
                "--repeats",
                str(args.repeats),
            ]
            res = json.loads(
                subprocess.run(cmd, capture_output=True, text=True, check=True).stdout.strip().splitlines()[-1]
            )
            times = [f"{res['median_s'] * 1e3:.1f}", f"{res['min_s'] * 1e3:.1f}"]
            row = [backend, device, f"{w}x{h}", f"{n:,}", *times, f"{res['peak_mb']:.0f}", f"{res['gpix_per_s']:.2f}"]
            print(" | ".join(row), flush=True)
            rows.append(row)
    headers = [
        "backend",
        "device",
        "image",
        "Gaussians",
        "fwd+bwd median (ms)",
        "min (ms)",
        "peak mem (MB)",
        "G gauss*px/s",
    ]
    table = markdown_table(headers, rows)
    print(table)
    if not args.no_append:
        note = (
            "Forward + backward of colour, depth, silhouette and 3 semantic channels; gradients to every "
            f"Gaussian parameter and the pose; median of {args.repeats} after 2 warm-ups. Peak memory is the "
            "process's max RSS on CPU (includes the Python/torch baseline) or torch's peak allocation on CUDA."
        )
        append_section("Renderer: forward + backward", note + "\n\n" + table)


if __name__ == "__main__":
    main()
