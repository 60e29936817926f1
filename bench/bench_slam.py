"""SLAM benchmark: per-frame tracking/mapping time, FPS, Gaussians, memory and accuracy of a whole run.

Runs ``run_offline`` (the same code as ``sgs-slam run``) on a dataset folder or MCAP bag (default:
the built-in synthetic room), prints a table, writes ``timing.png`` (time per frame and Gaussian
count) into the run folder and appends the table to BENCHMARKS.md. ``--profile K`` adds a second
pass that profiles K frames (after ``--profile-warmup`` unprofiled ones) with torch.profiler and
breaks the time down by the pipeline's ``record_function`` labels (track.render, map.backward, ...).

    python bench/bench_slam.py [INPUT] [--preset P] [--device cpu|cuda] [--max-frames N]
                               [--downscale F] [--set KEY=VALUE] [--profile K] [--realtime [HZ]]
                               [--no-append]
"""

from __future__ import annotations

import argparse
import resource
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch.autograd import DeviceType
from torch.profiler import ProfilerActivity, profile

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import append_section, markdown_table
from bench.plot import Series, line_panel, save_panels
from sgs_slam_core.cli.demo import default_room_dir, ensure_room
from sgs_slam_core.cli.run import camera_rate, default_preset
from sgs_slam_core.config import SlamConfig, load_config
from sgs_slam_core.datasets import DatasetOptions, open_dataset
from sgs_slam_core.datasets.base import Dataset
from sgs_slam_core.runner import RunResult, run_offline
from sgs_slam_core.runner.realtime import RealtimeOptions
from sgs_slam_core.slam.system import Slam

LABELS = ("data_loading", "upload", "track.render", "track.solve", "track.loss", "track.backward", "track.step",
          "densify", "keyframe_selection", "map.render", "map.loss", "map.backward", "map.step",
          "map.prune")  # fmt: skip


@dataclass(frozen=True)
class ProfileRow:
    """Time spent under one record_function label, per profiled frame."""

    label: str
    host_ms: float  # wall time on the host inside the label (children included)
    device_ms: float  # CUDA kernel time launched inside it (0 on the CPU)
    calls: int


def _percentile(values: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(values), q)) if values else float("nan")


def summary_rows(result: RunResult, dataset: Dataset, preset: str) -> list[list[object]]:
    """One row per run: the columns of the results table."""
    steps, m = result.steps, result.metrics
    track = [s.track.time_s * 1e3 for s in steps]
    total = [(s.track.time_s + s.map.time_s) * 1e3 for s in steps]
    iters = [s.track.result.iterations for s in steps if s.track.result is not None]
    k = dataset.intrinsics

    def cm(key: str) -> str:
        return f"{m[key] * 100:.2f}" if m.get(key) is not None else "-"

    gpu = f"{torch.cuda.max_memory_allocated() / 2**20:.0f}" if result.slam.device.type == "cuda" else "-"
    realtime = (
        f"{m['realtime_hz']:.0f} Hz: {m['frames_tracked']}/{m['frames_in']}" if m.get("realtime_hz") else "lockstep"
    )
    return [
        [
            f"{dataset.name} {m.get('frames_in', len(steps))} fr",
            f"{k.width}x{k.height}",
            preset,
            str(result.slam.device),
            realtime,
            f"{np.median(track):.0f} / {_percentile(track, 95):.0f}",
            f"{m['map_ms_per_frame']:.0f}",
            f"{np.median(total):.0f}",
            f"{m['fps']:.2f}",
            f"{np.mean(iters):.1f}" if iters else "-",
            f"{m['num_gaussians']:,}",
            f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f}",
            gpu,
            cm("ate_rmse_m"),
            f"{m['psnr_db']:.2f}" if m.get("psnr_db") is not None else "-",
            cm("depth_l1_m"),
            f"{m['miou'] * 100:.1f}" if m.get("miou") is not None else "-",
        ]
    ]


SUMMARY_HEADERS = ["input", "size", "preset", "device", "mode: tracked/in", "track ms (median / p95)", "map ms (mean)",
                   "total ms (median)", "FPS", "track iters", "Gaussians", "peak host MB", "peak GPU MB",
                   "ATE cm", "PSNR dB", "depth L1 cm", "mIoU %"]  # fmt: skip


def timing_plot(path: Path, result: RunResult, title: str) -> None:
    """Time per frame (tracking, mapping, total) over one panel, Gaussian count under it."""
    steps = result.steps
    track = np.array([s.track.time_s * 1e3 for s in steps])
    mapping = np.array([s.map.time_s * 1e3 for s in steps])
    times = [
        Series("tracking", track, (200, 90, 30)),
        Series("mapping", mapping, (40, 140, 40)),
        Series("total", track + mapping, (0, 0, 0)),
    ]
    count = [Series("Gaussians (k)", np.array([s.num_gaussians / 1e3 for s in steps]), (30, 30, 200))]
    save_panels(path, [line_panel(times, f"time per frame, {title}", "ms"), line_panel(count, "map size", "k")])


@dataclass(frozen=True)
class Profile:
    """What ``profile_frames`` measured: rows per label, wall ms per frame, the busiest host operators."""

    rows: list[ProfileRow]
    wall_ms: float
    top_ops: list[ProfileRow]  # by self host time, per frame (device_ms: their self device time)
    syncs: dict[str, float]  # host-blocking calls per frame, by name


# operators and runtime calls that make the host wait for the device (a host read of a device value)
SYNC_EVENTS = ("aten::_local_scalar_dense", "cudaStreamSynchronize", "cudaDeviceSynchronize", "cudaMemcpyAsync")


def profile_frames(dataset: Dataset, config: SlamConfig, warmup: int, count: int) -> Profile:
    """Profile frames warmup..warmup+count-1 of a fresh run."""
    torch.manual_seed(config.seed)
    slam = Slam(config, dataset.label_table)
    for i in range(min(warmup, len(dataset) - 1)):
        slam.process(dataset[i])
    frames = range(min(warmup, len(dataset) - 1), min(warmup + count, len(dataset)))
    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if slam.device.type == "cuda" else [])
    with profile(activities=activities) as prof:
        t0 = time.perf_counter()
        for i in frames:
            slam.process(dataset[i])
        if slam.device.type == "cuda":
            torch.cuda.synchronize()
        wall_s = time.perf_counter() - t0
    n = max(len(frames), 1)
    averages = prof.key_averages()  # aggregates every event: once, not per label
    rows = [row for label in LABELS if (row := _label_row(averages, label, n)) is not None]
    host_ops = [e for e in averages if getattr(e, "device_type", DeviceType.CPU) == DeviceType.CPU]
    ops = sorted((e for e in host_ops if e.key not in LABELS), key=lambda e: e.self_cpu_time_total, reverse=True)
    top = [
        ProfileRow(
            e.key, e.self_cpu_time_total / 1e3 / n, getattr(e, "self_device_time_total", 0.0) / 1e3 / n, e.count // n
        )
        for e in ops[:15]
    ]
    syncs = {name: sum(e.count for e in host_ops if e.key == name) / n for name in SYNC_EVENTS}
    return Profile(rows, wall_s * 1e3 / n, top, syncs)


def _label_row(averages: list, label: str, frames: int) -> ProfileRow | None:
    """Host and device time under one record_function label, per frame.

    With CUDA activity a label appears twice in ``key_averages()``: the host range (CPU device type:
    its wall time, and the device time of the kernels launched inside it) and a GPU-side annotation
    of the same name (no host time). Host time comes from the former; device time from whichever of
    the two saw the kernels (the larger; they describe the same kernels, so they are not added).
    """
    host_us = device_host_view_us = device_annotation_us = 0.0
    calls = 0
    for e in averages:
        if e.key != label:
            continue
        on_host = getattr(e, "device_type", DeviceType.CPU) == DeviceType.CPU
        if on_host:
            host_us += e.cpu_time_total
            device_host_view_us += getattr(e, "device_time_total", 0.0)
            calls += e.count
        else:
            device_annotation_us += getattr(e, "device_time_total", 0.0)
    if calls == 0 and device_annotation_us == 0:
        return None
    device_us = max(device_host_view_us, device_annotation_us)
    return ProfileRow(label, host_us / 1e3 / frames, device_us / 1e3 / frames, calls // frames)


def profile_table(rows: list[ProfileRow], wall_ms: float, device: str) -> str:
    """Markdown table: label, host ms/frame, share of the profiled wall time, device ms, calls."""
    labelled = sum(r.host_ms for r in rows)  # the labels do not nest
    body = [
        [
            r.label,
            f"{r.host_ms:.2f}",
            f"{100 * r.host_ms / wall_ms:.1f}",
            f"{r.device_ms:.2f}" if device == "cuda" else "-",
            r.calls,
        ]
        for r in rows
    ]
    body.append(
        [
            "(unlabelled: Python, guard, bookkeeping)",
            f"{wall_ms - labelled:.2f}",
            f"{100 * (wall_ms - labelled) / wall_ms:.1f}",
            "-",
            "-",
        ]
    )
    table = markdown_table(["label", "host ms/frame", "% of frame", "device ms/frame", "calls/frame"], body)
    if device == "cuda":
        busy = sum(r.device_ms for r in rows)
        table += (
            f"\n\nDevice time under the labels: {busy:.1f} ms of {wall_ms:.1f} ms per frame "
            f"({100 * busy / wall_ms:.0f} % busy)."
        )
    return table


def ops_table(prof: Profile) -> str:
    """Markdown: the operators with the most self host time per frame, and the host waits per frame."""
    body = [[f"`{r.label}`", f"{r.host_ms:.2f}", f"{r.device_ms:.2f}", r.calls] for r in prof.top_ops]
    table = markdown_table(["operator", "self host ms/frame", "self device ms/frame", "calls/frame"], body)
    waits = ", ".join(f"`{name}` {count:.0f}" for name, count in prof.syncs.items() if count > 0) or "none"
    return table + f"\n\nHost waits on the device per frame: {waits}."


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("input", nargs="?", type=Path, help="dataset folder or MCAP bag (default: the synthetic room)")
    parser.add_argument("--format", default="auto", help="dataset format (default: detect)")
    parser.add_argument("--preset", help="config preset (default: chosen from the dataset)")
    parser.add_argument("--device", choices=["auto", "cpu", "cuda"], default="auto")
    parser.add_argument("--max-frames", type=int, help="process at most N frames")
    parser.add_argument("--downscale", type=float, help="divide the image size by F (room default: 2 = 160x120)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--out", type=Path, help="run folder (default: a temporary folder)")
    parser.add_argument("--profile", type=int, default=0, metavar="K", help="profile K frames in a second pass")
    parser.add_argument("--profile-warmup", type=int, default=20, help="unprofiled frames before the profiled ones")
    parser.add_argument(
        "--realtime",
        nargs="?",
        const="stamps",
        type=camera_rate,
        metavar="HZ",
        help="replay as a live camera (frames at their stamps, or HZ); default: lockstep",
    )
    parser.add_argument("--no-append", action="store_true", help="print only, do not append to BENCHMARKS.md")
    args = parser.parse_args()

    data = args.input or ensure_room(default_room_dir())
    downscale = args.downscale or (2.0 if args.input is None else 1.0)
    preset = args.preset or default_preset(data, args.format)
    config = load_config(preset, None, [*args.overrides, f"device={args.device}"])
    dataset = open_dataset(data, args.format, DatasetOptions(max_frames=args.max_frames, downscale=downscale))
    out = args.out or Path(tempfile.mkdtemp(prefix="bench_slam_"))
    k = dataset.intrinsics
    print(f"{dataset.name}: {len(dataset)} frames at {k.width}x{k.height}, preset {preset}", file=sys.stderr)
    realtime = None if args.realtime is None else RealtimeOptions(None if args.realtime == "stamps" else args.realtime)
    result = run_offline(
        dataset, config, out, overwrite=True, provenance={"input": str(data), "bench": True}, realtime=realtime
    )
    mode = "" if realtime is None else f", realtime {args.realtime}"
    title = f"{dataset.name} {k.width}x{k.height}, {preset}, {result.slam.device}{mode}"
    timing_plot(out / "timing.png", result, title)
    body = markdown_table(SUMMARY_HEADERS, summary_rows(result, dataset, preset))
    body += f"\n\nOverrides: {args.overrides or 'none'}. Run folder (frames.csv, metrics.json, timing.png): `{out}`.\n"
    if args.profile > 0:
        prof = profile_frames(dataset, config, args.profile_warmup, args.profile)
        body += (
            f"\nProfile of frames {args.profile_warmup}..{args.profile_warmup + args.profile - 1} "
            f"(torch.profiler, {prof.wall_ms:.1f} ms/frame under the profiler):\n\n"
            + profile_table(prof.rows, prof.wall_ms, result.slam.device.type)
            + "\n\n"
            + ops_table(prof)
            + "\n"
        )
    print(body)
    print(f"plot: {out / 'timing.png'}")
    if not args.no_append:
        append_section(f"SLAM: {title}", body)


if __name__ == "__main__":
    main()
