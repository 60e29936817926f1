"""Long-run benchmark: the synthetic room's orbit played back and forth for thousands of frames.

A run on a robot lasts hours, not 200 frames; here the camera keeps revisiting one room, so memory,
the Gaussian count and the time per frame must stop growing once the room has been seen. The
orbit (``--loop-frames`` frames at ``--width`` x ``--height``) is rendered once and replayed
forwards and backwards (a loop is there and back) through ``Slam.process`` in this process, with
increasing stamps. Every ``--every`` frames the resident set size, the Gaussians and keyframes held
(and their bytes) and the time per frame are sampled. Writes a JSON file and a plot under
bench/results/, prints a per-loop table and appends it to BENCHMARKS.md.

    python bench/bench_longrun.py [--width 640 --height 480] [--frames 2000] [--loop-frames 120]
        [--tracking-iterations N] [--mapping-iterations N] [--device cuda] [--set key=value ...] [--no-append]

Ctrl-C or SIGTERM (``timeout``) ends the run early; what was measured is still reported.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import signal
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import REPO, append_section, commit, generate_apart, markdown_table
from bench.plot import Series, line_panel, save_panels
from sgs_slam_core.config import load_config
from sgs_slam_core.config.schema import SlamConfig
from sgs_slam_core.datasets import open_dataset
from sgs_slam_core.datasets.base import Dataset
from sgs_slam_core.metrics import ate
from sgs_slam_core.render.output import camera_covariances, to_camera
from sgs_slam_core.render.projection import project_gaussians
from sgs_slam_core.render.tiling import plan_tiles
from sgs_slam_core.slam.footprint import footprint
from sgs_slam_core.slam.system import Slam
from sgs_slam_core.synthetic import SynthConfig

RESULTS = REPO / "bench" / "results"


@dataclass(frozen=True)
class Sample:
    """The run's state after ``frames`` frames."""

    frames: int
    rss_mb: float  # resident set now
    peak_rss_mb: float  # highest resident set so far
    gaussians: int
    gaussian_mb: float
    keyframes: int
    keyframe_mb: float
    evicted: int
    s_per_frame: float  # mean Slam.process wall time over the frames since the last sample
    cpu_s_per_frame: float  # the same in CPU time of this process (all threads): steadier on a shared machine
    gpu_peak_mb: float  # highest CUDA memory allocated by torch so far (0 on the CPU)
    track_s: float  # mean tracking wall time per frame since the last sample
    map_s: float  # mean densification + mapping wall time per frame since the last sample
    renders: float  # mean renderings per tracked frame since the last sample
    intersections: int  # Gaussian x 16-pixel-tile pairs of the map seen from the run's first pose (render work)
    scale_p90_mm: float  # 90th percentile of the Gaussians' largest scale (mm)


@dataclass(frozen=True)
class LoopRow:
    """Means over one loop (there and back) of the orbit."""

    loop: int
    frames: str
    rss_mb: float
    peak_rss_mb: float
    gaussians: float
    keyframes: float
    keyframe_mb: float
    s_per_frame: float
    cpu_s_per_frame: float
    gpu_peak_mb: float
    ate_cm: float
    track_s: float
    map_s: float
    intersections: float


def rss_mb() -> float:
    """Resident memory of this process now (MB)."""
    return int(Path("/proc/self/statm").read_text().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def peak_rss_mb() -> float:
    """Highest resident memory of this process so far (MB; Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def gpu_peak_mb(device: str) -> float:
    """Highest memory torch has allocated on ``device`` so far (MB; 0 off CUDA)."""
    return torch.cuda.max_memory_allocated(device) / 2**20 if device.startswith("cuda") else 0.0


@torch.no_grad()
def render_work(slam: Slam, c2w: np.ndarray, tile: int = 16) -> int:
    """Gaussian x tile pairs when the map is rendered from ``c2w`` [4, 4]: the compositor's work, untimed."""
    g, k, s = slam.gaussians, slam.intrinsics, slam.config.render
    if k is None or not len(g):
        return 0
    w2c = torch.as_tensor(np.linalg.inv(c2w), dtype=g.means.dtype, device=g.means.device)
    cam = to_camera(g, w2c, with_semantics=False)
    proj = project_gaussians(
        cam.means,
        cam.opacities,
        k,
        s,
        scales=cam.scales if g.isotropic else None,
        covars_cam=None if g.isotropic else camera_covariances(cam),
    )
    return plan_tiles(
        proj.means2d, proj.radii, proj.depths, k.width, k.height, tile, s.chunk_elements
    ).num_intersections


def scale_p90_mm(slam: Slam) -> float:
    """90th percentile of the Gaussians' largest scale (mm; over every 7th Gaussian); 0 for an empty map."""
    g = slam.gaussians
    if not len(g):
        return 0.0
    return 1000 * float(torch.quantile(torch.exp(g.log_scales.detach()).amax(dim=1).float()[::7], 0.9))


def order(loop_frames: int, count: int) -> list[int]:
    """``count`` dataset positions going there and back over ``loop_frames`` frames."""
    period = [*range(loop_frames), *range(loop_frames - 2, 0, -1)]
    return [period[i % len(period)] for i in range(count)]


def run(dataset: Dataset, config: SlamConfig, count: int, every: int) -> tuple[list[Sample], np.ndarray, np.ndarray]:
    """Process ``count`` frames going back and forth (Ctrl-C ends early); samples, estimated and true c2w [T, 4, 4]."""
    slam = Slam(config, dataset.label_table)
    slam.prepare(lambda line: print(line, flush=True))
    est, gt, samples = [], [], []
    try:
        _loop(slam, dataset, count, every, est, gt, samples)
    except KeyboardInterrupt:  # a long run stopped early still reports what it measured
        print(f"stopped after {len(est)} frames", flush=True)
    return samples, np.stack(est[: len(gt)]), np.stack(gt[: len(est)])


def _loop(slam: Slam, dataset: Dataset, count: int, every: int, est: list, gt: list, samples: list[Sample]) -> None:
    spent = cpu = tracking = mapping = renders = 0.0
    for i, pos in enumerate(order(len(dataset), count)):
        frame = replace(dataset[pos], stamp_ns=10**9 + i * 33_333_333)  # 30 Hz stamps, always increasing
        t0, c0 = time.perf_counter(), time.process_time()
        step = slam.process(frame)
        spent += time.perf_counter() - t0
        cpu += time.process_time() - c0
        tracking += step.track.time_s
        mapping += step.map.time_s
        result = step.track.result
        renders += 0 if result is None else (result.renders or result.iterations)
        gt.append(frame.gt_c2w)
        est.append(step.c2w)
        if (i + 1) % every == 0 or i + 1 == count:
            fp = footprint(slam)
            done = (i + 1) - (samples[-1].frames if samples else 0)
            mb = 2**20
            samples.append(
                Sample(
                    i + 1,
                    rss_mb(),
                    peak_rss_mb(),
                    fp.gaussians,
                    fp.gaussian_bytes / mb,
                    fp.keyframes,
                    fp.keyframe_bytes / mb,
                    fp.keyframes_evicted,
                    spent / done,
                    cpu / done,
                    gpu_peak_mb(slam.config.device),
                    tracking / done,
                    mapping / done,
                    renders / done,
                    render_work(slam, est[0]),
                    scale_p90_mm(slam),
                )
            )
            spent = cpu = tracking = mapping = renders = 0.0
            s = samples[-1]
            print(
                f"{s.frames:6d} frames  {s.rss_mb:7.0f} MB (peak {s.peak_rss_mb:.0f})  {s.gaussians:8,d} G "
                f"({s.gaussian_mb:.0f} MB)  {s.keyframes:4d} kf ({s.keyframe_mb:.0f} MB, {s.evicted} evicted)  "
                f"{s.s_per_frame:.2f} s/frame ({s.cpu_s_per_frame:.2f} CPU s; track {s.track_s:.2f}, "
                f"{s.renders:.1f} renders; map {s.map_s:.2f})  {s.intersections / 1e6:.2f} M tile pairs  "
                f"p90 scale {s.scale_p90_mm:.1f} mm" + (f"  GPU peak {s.gpu_peak_mb:.0f} MB" if s.gpu_peak_mb else ""),
                flush=True,
            )


def per_loop(samples: list[Sample], est: np.ndarray, gt: np.ndarray, period: int) -> list[LoopRow]:
    """Means of the samples falling in each loop, and the ATE of that loop's frames (aligned per loop)."""
    rows = []
    for loop in range(-(-len(est) // period)):
        lo, hi = loop * period, min((loop + 1) * period, len(est))
        inside = [s for s in samples if lo < s.frames <= hi]
        if hi - lo < period // 2 or not inside:
            continue  # a short last piece says little about a loop
        rows.append(
            LoopRow(
                loop + 1,
                f"{lo + 1}-{hi}",
                float(np.mean([s.rss_mb for s in inside])),
                max(s.peak_rss_mb for s in inside),
                float(np.mean([s.gaussians for s in inside])),
                float(np.mean([s.keyframes for s in inside])),
                float(np.mean([s.keyframe_mb for s in inside])),
                float(np.mean([s.s_per_frame for s in inside])),
                float(np.mean([s.cpu_s_per_frame for s in inside])),
                max(s.gpu_peak_mb for s in inside),
                100 * ate(est[lo:hi], gt[lo:hi]).rmse,
                float(np.mean([s.track_s for s in inside])),
                float(np.mean([s.map_s for s in inside])),
                float(np.mean([s.intersections for s in inside])),
            )
        )
    return rows


def drift(rows: list[LoopRow], field: str) -> float:
    """Largest relative change of a per-loop mean from loop 2 on, against loop 2 (0.05 = 5 %)."""
    values = [getattr(r, field) for r in rows if r.loop >= 2]
    if len(values) < 2:
        return float("nan")
    return max(abs(v - values[0]) for v in values) / max(abs(values[0]), 1e-9)


def plot(samples: list[Sample], path: Path, title: str) -> None:
    """Memory, map size and time per frame against frames."""
    x = samples[1].frames - samples[0].frames if len(samples) > 1 else 1
    panels = [
        line_panel(
            [
                Series("resident set", np.array([s.rss_mb for s in samples]), (200, 90, 0)),
                Series("keyframe images", np.array([s.keyframe_mb for s in samples]), (30, 30, 200)),
                Series("Gaussian tensors", np.array([s.gaussian_mb for s in samples]), (40, 140, 40)),
            ],
            f"{title}: host memory",
            "MB",
            x_label="frames",
            x_step=x,
        ),
        line_panel(
            [
                Series("Gaussians / 1000", np.array([s.gaussians / 1e3 for s in samples]), (40, 140, 40)),
                Series("keyframes held", np.array([s.keyframes for s in samples], float), (30, 30, 200)),
            ],
            "map size",
            "count",
            x_label="frames",
            x_step=x,
        ),
        line_panel(
            [
                Series("wall", np.array([s.s_per_frame for s in samples]), (120, 40, 160)),
                Series("CPU (all threads)", np.array([s.cpu_s_per_frame for s in samples]), (0, 140, 220)),
                Series("tracking", np.array([s.track_s for s in samples]), (200, 90, 0)),
                Series("densify + mapping", np.array([s.map_s for s in samples]), (40, 140, 40)),
            ],
            "Slam.process",
            "s",
            x_label="frames",
            x_step=x,
        ),
        line_panel(
            [
                Series("tile pairs / 1e5", np.array([s.intersections / 1e5 for s in samples]), (120, 40, 160)),
                Series("p90 Gaussian scale (mm)", np.array([s.scale_p90_mm for s in samples]), (0, 140, 220)),
            ],
            "render work from the first pose",
            "count",
            x_label="frames",
            x_step=x,
        ),
    ]
    path.parent.mkdir(parents=True, exist_ok=True)
    save_panels(path, panels)


def report(rows: list[LoopRow], samples: list[Sample], plot_path: Path, what: str) -> str:
    """Markdown: what ran, the drift from loop 2 on, the plot and the per-loop table."""
    table = markdown_table(
        [
            "loop",
            "frames",
            "RSS MB",
            "peak RSS MB",
            "Gaussians",
            "keyframes",
            "keyframe MB",
            "s/frame",
            "CPU s/frame",
            "GPU peak MB",
            "ATE cm",
            "track s",
            "map s",
            "tile pairs M",
        ],
        [
            [
                r.loop,
                r.frames,
                f"{r.rss_mb:.0f}",
                f"{r.peak_rss_mb:.0f}",
                f"{r.gaussians:,.0f}",
                f"{r.keyframes:.0f}",
                f"{r.keyframe_mb:.1f}",
                f"{r.s_per_frame:.2f}",
                f"{r.cpu_s_per_frame:.2f}",
                f"{r.gpu_peak_mb:.0f}" if r.gpu_peak_mb else "-",
                f"{r.ate_cm:.2f}",
                f"{r.track_s:.2f}",
                f"{r.map_s:.2f}",
                f"{r.intersections / 1e6:.2f}",
            ]
            for r in rows
        ],
    )
    drifts = ", ".join(
        f"{name} {100 * drift(rows, f):.1f} %"
        for name, f in (
            ("RSS", "rss_mb"),
            ("Gaussians", "gaussians"),
            ("keyframe MB", "keyframe_mb"),
            ("wall time per frame", "s_per_frame"),
            ("CPU time per frame", "cpu_s_per_frame"),
            ("tracking time", "track_s"),
            ("mapping time", "map_s"),
            ("tile pairs", "intersections"),
        )
    )
    return (
        f"{what} Peak resident memory {max(s.peak_rss_mb for s in samples):.0f} MB. Largest change of a loop's "
        f"mean from loop 2 on (against loop 2): {drifts}.\n\n![long run]({plot_path.relative_to(REPO)})\n\n"
        f"{table}\n"
    )


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def _tracking(config: SlamConfig) -> str:
    """The tracker and its iterations, as the report names them."""
    t = config.tracking
    return f"Adam ({t.adam.iterations} iterations)" if t.method == "adam" else f"{t.method.replace('_', '-')}"


def main() -> int:
    """Render the orbit, run it long, report."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--width", type=int, default=320)
    p.add_argument("--height", type=int, default=240)
    p.add_argument("--frames", type=int, default=2000, help="frames processed in all")
    p.add_argument("--loop-frames", type=int, default=120, help="orbit frames rendered (1.5 degrees apart)")
    p.add_argument("--preset", default="synthetic")
    p.add_argument("--device", default="cpu", help="cpu or cuda")
    p.add_argument("--tracking-iterations", type=int, help="reduced for time (the report says so)")
    p.add_argument("--mapping-iterations", type=int, help="reduced for time (the report says so)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config overrides")
    p.add_argument("--every", type=int, default=10, help="sample every N frames")
    p.add_argument("--tag", default="", help="appended to the result files' names")
    p.add_argument("--no-append", action="store_true", help="print only; leave BENCHMARKS.md alone")
    args = p.parse_args()
    signal.signal(signal.SIGTERM, _interrupt)  # `timeout` ends the run like Ctrl-C: the report still comes
    overrides = [f"device={args.device}", *args.set]
    if args.tracking_iterations is not None:
        overrides.append(f"tracking.adam.iterations={args.tracking_iterations}")
    if args.mapping_iterations is not None:
        it = args.mapping_iterations
        overrides += [f"mapping.iterations={it}", f"mapping.prune_iterations=[0,{it // 2}]"]
    config = load_config(args.preset, overrides=overrides)
    size = f"{args.width}x{args.height}"
    with tempfile.TemporaryDirectory() as tmp:
        orbit = SynthConfig(width=args.width, height=args.height, frames=args.loop_frames)
        scene = generate_apart(Path(tmp) / "orbit", orbit)
        samples, est, gt = run(open_dataset(scene), config, args.frames, args.every)
    period = 2 * (args.loop_frames - 1)
    rows = per_loop(samples, est, gt, period)
    name = f"longrun_{size}_{args.frames}{'_' + args.tag if args.tag else ''}"
    plot_path = RESULTS / f"{name}.png"
    plot(samples, plot_path, f"room orbit {size}")
    (RESULTS / f"{name}.json").write_text(
        json.dumps(
            {
                "commit": commit(),
                "overrides": overrides,
                "samples": [asdict(s) for s in samples],
                "loops": [asdict(r) for r in rows],
            },
            indent=1,
        )
    )
    what = (
        f"The synthetic room's orbit ({args.loop_frames} frames at {size}, there and back: {period} frames a "
        f"loop) for {len(est):,} of {args.frames:,} frames through `Slam.process` (lockstep, {args.device}), "
        f"preset `{args.preset}`, {_tracking(config)} tracking and {config.mapping.iterations} mapping iterations"
        f"{' (reduced for time)' if args.tracking_iterations or args.mapping_iterations else ''}; keyframes "
        f"capped at {config.keyframes.max_keyframes} / {config.keyframes.max_megabytes} MiB."
    )
    body = report(rows, samples, plot_path, what)
    print(body)
    if not args.no_append:
        append_section(f"Long run: room orbit {size}, {args.frames:,} frames", body)
    return 0


if __name__ == "__main__":
    sys.exit(main())
