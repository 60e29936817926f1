"""Soak benchmark: slam_node (live mode) fed a long synthetic stream; resident memory over time.

The tiny synthetic scene (64x48, 12 frames), or with ``--width``/``--height`` the room's orbit
(``--loop-frames`` frames), is played back and forth at ``--rate-hz`` with increasing stamps, so
after the first pass every view has been seen and the map stops growing: from then on memory must
stay flat. slam_node runs in this process (as in the ROS tests) with
its normal outputs on; every ``--every`` frames the resident set size, the Gaussian count, the
frames tracked, the keyframes held and the drops are sampled. Writes a plot (memory and map size
over frames) and a table, and appends both to BENCHMARKS.md.

    python bench/bench_soak.py [--frames 10000] [--rate-hz 100] [--width 320 --height 240] [--no-append]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

from bench.common import REPO, append_section, generate_apart, markdown_table
from bench.plot import Series, line_panel, save_panels
from sgs_slam_core.frame import Frame
from sgs_slam_core.slam.footprint import footprint
from sgs_slam_core.synthetic import SynthConfig, preset_config
from test.ros.helpers import Feeder, Spinner, new_context, node_params, shut_down, tiny_frames, wait_for

if TYPE_CHECKING:
    from sgs_slam_ros.tracking_node import TrackingNode

RESULTS = REPO / "bench" / "results"


@dataclass(frozen=True)
class Sample:
    """The node's state after ``frames`` frames were published."""

    frames: int
    elapsed_s: float
    rss_mb: float
    gaussians: int
    tracked: int
    failed: int  # tracked, but flagged by the failure guard (not mapped)
    keyframes: int
    keyframe_mb: float  # host bytes of the keyframes' images held
    drops: int
    errors: int


def rss_mb() -> float:
    """Resident memory of this process now (MB)."""
    return int(Path("/proc/self/statm").read_text().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def stream(frames: list[Frame], count: int, rate_hz: float):
    """``count`` frames going back and forth over ``frames``, stamped at ``rate_hz``."""
    order = [*range(len(frames)), *range(len(frames) - 2, 0, -1)]
    for i in range(count):
        yield i, replace(frames[order[i % len(order)]], stamp_ns=10**9 + round(i * 1e9 / rate_hz))


def _sample(tracking: TrackingNode, published: int, elapsed_s: float) -> Sample:
    """The tracking node's state now, as /diagnostics counts it."""
    st, slam, a = tracking.pipeline.stats, tracking.pipeline.slam, tracking.assembler
    held = footprint(slam)
    return Sample(
        published,
        elapsed_s,
        rss_mb(),
        held.gaussians,
        st.tracked,
        st.tracking_failures,
        held.keyframes,
        held.keyframe_bytes / 2**20,
        st.dropped_frames + a.colour_dropped + a.frames_rejected,
        st.errors,
    )


def soak(scene: Path, count: int, rate_hz: float, every: int, iterations: int) -> tuple[list[Sample], str]:
    """Publish ``count`` frames into an in-process slam_node, sampling it every ``every`` frames.

    Returns the samples and the tracker the node ran.
    """
    from sgs_slam_ros.slam_node import build_slam_nodes  # noqa: PLC0415 - rclpy only when running

    frames = tiny_frames(scene)  # depth in millimetres, as a 16UC1 camera delivers it
    ctx = new_context()
    overrides = [f"tracking.adam.iterations={iterations}", f"mapping.iterations={iterations}"]
    params = node_params(
        overrides=overrides,
        lockstep=False,
        input_qos="best_effort",
        render_rate_hz=2.0,
        points_rate_hz=1.0,
        gaussians_rate_hz=0.5,
        map_path=str(scene / "m.sgsmap"),
    )
    nodes = build_slam_nodes(context=ctx, parameter_overrides=params)
    feeder = Feeder(ctx)
    spinner = Spinner(ctx, [*nodes, feeder], threads=1)  # as `ros2 run` spins the nodes
    tracking = nodes[0]
    tracker = tracking.pipeline.slam.config.tracking.method
    samples: list[Sample] = []
    try:
        assert wait_for(feeder.connected, 20.0), "slam_node did not subscribe"
        start = time.monotonic()

        def sample(published: int) -> None:
            samples.append(_sample(tracking, published, time.monotonic() - start))
            s = samples[-1]
            print(
                f"{published:6d} frames  {s.rss_mb:7.1f} MB  {s.gaussians:6d} G  "
                f"{s.tracked:5d} tracked ({s.failed} failed)  {s.keyframes:4d} keyframes",
                flush=True,
            )

        sample(0)
        for i, frame in stream(frames, count, rate_hz):
            feeder.publish(frame)
            if (i + 1) % every == 0:
                sample(i + 1)
            delay = start + (i + 1) / rate_hz - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        tracking.pipeline.wait_idle(60.0)
    finally:
        shut_down(ctx, [*nodes, feeder], spinner)
    return samples, tracker


def report(
    samples: list[Sample], count: int, rate_hz: float, iterations: int, size: str, loop: int, tracker: str
) -> str:
    """Markdown: the plot, a table every 10 % of the stream, and the growth after the first tenth."""
    every = samples[1].frames - samples[0].frames
    panels = [
        line_panel(
            [Series("resident set", np.array([s.rss_mb for s in samples]), (200, 90, 0))],
            "slam_node memory",
            "MB",
            x_label="frames published",
            x_step=every,
        ),
        line_panel(
            [
                Series("Gaussians", np.array([s.gaussians / 1e3 for s in samples]), (40, 140, 40)),
                Series("keyframes / 10", np.array([s.keyframes / 10 for s in samples]), (30, 30, 200)),
                Series("frames tracked / 100", np.array([s.tracked / 100 for s in samples]), (150, 150, 150)),
            ],
            "map size",
            "thousands of Gaussians",
            x_label="frames published",
            x_step=every,
        ),
    ]
    plot = RESULTS / f"soak_slam_node_{size}.png"
    plot.parent.mkdir(parents=True, exist_ok=True)
    save_panels(plot, panels)
    picked = sorted({*range(0, len(samples), max(1, len(samples) // 10)), len(samples) - 1})
    rows = [
        [
            f"{s.frames:,}",
            f"{s.elapsed_s:.0f}",
            f"{s.rss_mb:.0f}",
            f"{s.gaussians:,}",
            f"{s.tracked:,}",
            f"{s.failed:,}",
            s.keyframes,
            f"{s.keyframe_mb:.1f}",
            f"{s.drops:,}",
            s.errors,
        ]
        for s in (samples[i] for i in picked)
    ]
    tenth = samples[max(1, len(samples) // 10)]
    last = samples[-1]
    per_k = (last.rss_mb - tenth.rss_mb) / max((last.frames - tenth.frames) / 1000, 1e-9)
    headers = ["frames published", "s", "RSS MB", "Gaussians", "tracked", "failed", "keyframes", "keyframe MB"]
    table = markdown_table([*headers, "drops", "errors"], rows)
    return (
        f"slam_node in live mode (best-effort input, outputs on) fed {count:,} frames of a synthetic scene "
        f"({size}, {loop} frames back and forth) at {rate_hz:g} Hz; {tracker.replace('_', '-')} tracking"
        f"{f' ({iterations} iterations)' if tracker == 'adam' else ''}, {iterations} mapping iterations. "
        f"Peak resident memory {max(s.rss_mb for s in samples):.0f} MB; from {tenth.frames:,} to {last.frames:,} "
        f"frames it went "
        f"{tenth.rss_mb:.0f} -> {last.rss_mb:.0f} MB ({per_k:+.2f} MB per 1,000 frames) while the map held "
        f"{tenth.gaussians:,} -> {last.gaussians:,} Gaussians and {tenth.keyframes} -> {last.keyframes} keyframes.\n\n"
        f"![soak]({plot.relative_to(REPO)})\n\n{table}\n"
    )


def main() -> int:
    """Run the soak and report it."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=10_000)
    parser.add_argument("--rate-hz", type=float, default=100.0)
    parser.add_argument("--every", type=int, default=50, help="sample every N frames")
    parser.add_argument("--iterations", type=int, default=5, help="mapping iterations (and the Adam tracker's)")
    parser.add_argument("--width", type=int, help="play the room's orbit at this size instead of the tiny scene")
    parser.add_argument("--height", type=int)
    parser.add_argument("--loop-frames", type=int, default=120, help="orbit frames (with --width/--height)")
    parser.add_argument("--no-append", action="store_true", help="print only; leave BENCHMARKS.md alone")
    args = parser.parse_args()
    height = args.height or (args.width or 0) * 3 // 4
    synth = preset_config("tiny") if args.width is None else SynthConfig(args.width, height, args.loop_frames)
    size = f"{synth.width}x{synth.height}"
    with tempfile.TemporaryDirectory() as tmp:
        scene = generate_apart(Path(tmp) / "scene", synth)
        samples, tracker = soak(scene, args.frames, args.rate_hz, args.every, args.iterations)
    body = report(samples, args.frames, args.rate_hz, args.iterations, size, synth.frames, tracker)
    print(body)
    if not args.no_append:
        append_section(f"Soak: slam_node, {args.frames:,} frames ({size})", body)
    return 0


if __name__ == "__main__":
    sys.exit(main())
