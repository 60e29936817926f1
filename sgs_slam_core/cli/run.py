"""``sgs-slam run``: the whole pipeline on a dataset folder or MCAP bag, writing a run folder."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from sgs_slam_core.cli.args import MAX_SEED, FloatRange, IntRange
from sgs_slam_core.cli.viewer_args import add_viewer_arguments, start_viewer, viewer_options_from_args
from sgs_slam_core.config import SlamConfig, list_presets, load_config
from sgs_slam_core.datasets import Dataset, DatasetOptions, dataset_format, formats, open_dataset
from sgs_slam_core.datasets.base import auto_downscale
from sgs_slam_core.datasets.label_noise import LABEL_NOISE_LEVELS, NoisyLabels
from sgs_slam_core.errors import DatasetError
from sgs_slam_core.runner import format_table, run_offline
from sgs_slam_core.runner.label_stream import LabelStream
from sgs_slam_core.runner.outputs import check_run_dir
from sgs_slam_core.runner.realtime import RealtimeOptions
from sgs_slam_core.slam.system import resolve_device

__all__ = ["add_label_arguments", "add_parser", "camera_rate", "default_preset", "open_input", "parse_topics", "run"]

TOPIC_KEYS = ("color", "camera_info", "depth", "semantic", "pose")


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the sub-command."""
    p = sub.add_parser(
        "run",
        help="run SLAM on a dataset folder or bag and evaluate it",
        description="Track, map and evaluate; writes trajectory.txt, metrics.json, config.yaml, map.ply, "
        "map.sgsmap, renders/ and trajectory.png to --out.",
    )
    p.add_argument("input", type=Path, help="dataset folder (TUM, Replica, ScanNet, synthetic) or MCAP bag")
    add_dataset_arguments(p)
    p.add_argument("--preset", choices=list_presets(), help="config preset (default: chosen from the dataset)")
    p.add_argument("--config", type=Path, help="YAML file applied after the preset")
    p.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a config value, e.g. --set tracking.adam.iterations=60 (repeatable)",
    )
    p.add_argument("--device", choices=["auto", "cpu", "cuda"], help="compute device (default: config)")
    p.add_argument("--out", type=Path, required=True, help="run folder (must be empty unless --overwrite)")
    p.add_argument("--overwrite", action="store_true", help="replace a non-empty run folder")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument(
        "--realtime",
        nargs="?",
        const="stamps",
        type=camera_rate,
        metavar="HZ",
        help="replay as a live camera: frames released at their recorded stamps (or HZ per second), "
        "dropped while tracking is busy; mapping runs beside it (default: lockstep)",
    )
    p.add_argument(
        "--preload-mb",
        type=FloatRange(0.0, 1e6),
        default=RealtimeOptions.preload_mb,
        metavar="MIB",
        help="with --realtime: decode up to this many MiB of frames before the camera starts, as a camera "
        "delivers decoded images (0..1e6, default %(default).0f; 0 = read each frame just before its release)",
    )
    add_label_arguments(p)
    add_viewer_arguments(p)
    p.set_defaults(func=run)


def add_label_arguments(p: argparse.ArgumentParser) -> None:
    """The labels' own stream (``--label-rate-hz``, ``--label-delay-ms``) and their mistakes (``--label-noise``)."""
    p.add_argument(
        "--label-rate-hz",
        type=FloatRange(0.01, 1000.0),
        metavar="HZ",
        help="with --realtime: the labels come as a segmenter's stream at HZ label images a second, apart "
        "from the frames, and are fused when they come (0.01..1000; default: every frame carries its labels)",
    )
    p.add_argument(
        "--label-delay-ms",
        type=FloatRange(0.0, 60000.0),
        metavar="MS",
        help="with --realtime: each label image comes MS after its frame (0..60000, default 0; implies the "
        "labels' own stream, at every frame's when --label-rate-hz is not given)",
    )
    p.add_argument(
        "--label-noise",
        choices=list(LABEL_NOISE_LEVELS),
        help="feed the labels degraded as a segmenter degrades them (regions flickering to another class, "
        "classes confused, boundaries bled, frames unlabelled) and score the map against the true labels",
    )
    p.add_argument(
        "--label-noise-seed",
        type=IntRange(0, MAX_SEED),
        default=0,
        metavar="N",
        help="with --label-noise: the seed its mistakes are drawn from (default %(default)s)",
    )


def camera_rate(text: str) -> float | str:
    """``--realtime`` value: a rate in Hz (0.1-1000), or ``stamps`` for the recorded time stamps."""
    if text == "stamps":
        return text
    try:
        hz = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a rate in Hz, got {text!r}") from None
    if not 0.1 <= hz <= 1000:
        raise argparse.ArgumentTypeError(f"rate must be in [0.1, 1000] Hz, got {hz:g}")
    return hz


def downscale_arg(text: str) -> float | str:
    """``--downscale`` value: a factor in 1..64, or ``auto`` (chosen from the input's width and the device)."""
    return "auto" if text == "auto" else FloatRange(1.0, 64.0)(text)


def resolve_downscale(args: argparse.Namespace, config: SlamConfig, topics: dict[str, str]) -> float:
    """``--downscale`` as a factor: ``auto`` opens the input once to read its width."""
    if args.downscale != "auto":
        return args.downscale
    native = open_input(args.input, args.format, DatasetOptions(max_frames=1), topics)
    return auto_downscale(native.intrinsics.width, resolve_device(config.device).type == "cpu")


def add_dataset_arguments(p: argparse.ArgumentParser) -> None:
    """Format and frame-selection options shared by run and eval."""
    p.add_argument("--format", default="auto", choices=["auto", *formats()], help="dataset format (default: detect)")
    p.add_argument("--max-frames", type=IntRange(1), help="process at most N frames (>= 1)")
    p.add_argument("--stride", type=IntRange(1), default=1, help="use every K-th frame (>= 1)")
    p.add_argument("--start", type=IntRange(0), default=0, help="first frame (>= 0)")
    p.add_argument(
        "--downscale",
        type=downscale_arg,
        default=1.0,
        help="divide the image size by F (1..64), or auto: 160 px wide on a CPU, the input size on a GPU",
    )
    p.add_argument(
        "--topic",
        dest="topics",
        action="append",
        default=[],
        metavar="KEY=NAME",
        help=f"bag topic of a stream, KEY one of {', '.join(TOPIC_KEYS)} (bags recorded elsewhere; repeatable)",
    )


def parse_topics(items: list[str]) -> dict[str, str]:
    """``["depth=/d", ...]`` -> ``{"depth": "/d"}``; an unknown key or a missing '=' raises DatasetError."""
    topics = {}
    for item in items:
        key, sep, name = item.partition("=")
        if not sep or key not in TOPIC_KEYS or not name.startswith("/"):
            raise DatasetError(f"--topic {item!r}: expected KEY=/topic with KEY one of {', '.join(TOPIC_KEYS)}")
        topics[key] = name
    return topics


def open_input(path: Path, fmt: str, options: DatasetOptions, topics: dict[str, str] | None = None) -> Dataset:
    """Open a dataset folder or bag; ``topics`` (bags only) rename the streams."""
    return open_dataset(path, fmt, options, topics)


def default_preset(path: Path, fmt: str) -> str:
    """The preset matching a dataset (synthetic scenes get ``synthetic``; a converted bag its folder's)."""
    return dataset_format(path, fmt).preset(path)


def _with_label_noise(dataset: Dataset, level: str | None, seed: int) -> Dataset:
    """``dataset`` feeding its labels degraded at the named level (itself without a level)."""
    if level is None:
        return dataset
    if not dataset.has_labels:
        raise DatasetError(f"--label-noise needs a dataset with label images; {dataset.name} has none")
    return NoisyLabels(dataset, LABEL_NOISE_LEVELS[level], seed)


def run(args: argparse.Namespace) -> int:
    """Open the dataset, resolve the config, run and print the metrics table."""
    check_run_dir(args.out, args.overwrite)
    if not args.input.exists():
        raise DatasetError(f"{args.input} does not exist")
    preset = args.preset or default_preset(args.input, args.format)
    overrides = [*args.overrides, *([f"device={args.device}"] if args.device else [])]
    config = load_config(preset, args.config, overrides)  # config errors surface before any data is read
    viewer_options = viewer_options_from_args(args)
    topics = parse_topics(args.topics)
    downscale = resolve_downscale(args, config, topics)
    options = DatasetOptions(start=args.start, stride=args.stride, max_frames=args.max_frames, downscale=downscale)
    truth = open_input(args.input, args.format, options, topics)
    dataset = _with_label_noise(truth, args.label_noise, args.label_noise_seed)
    auto = f" (downscale auto: {downscale:g})" if args.downscale == "auto" else ""
    size = f"{dataset.intrinsics.width}x{dataset.intrinsics.height}{auto}"
    print(f"{dataset.name}: {len(dataset)} frames at {size}, preset {preset}, device {config.device}", file=sys.stderr)
    provenance = {
        "input": str(args.input.resolve()),
        "format": dataset.name,
        "options": {
            "start": args.start,
            "stride": args.stride,
            "max_frames": args.max_frames,
            "downscale": downscale,
        },
        "topics": topics,
        "preset": preset,
        "config_file": str(args.config) if args.config else None,
        "overrides": overrides,
        "command": " ".join(sys.argv),
        "realtime": args.realtime,
        "label_rate_hz": args.label_rate_hz,
        "label_delay_ms": args.label_delay_ms,
        "label_noise": args.label_noise,
        "label_noise_seed": args.label_noise_seed if args.label_noise else None,
    }
    realtime = None
    separate_labels = args.label_rate_hz is not None or args.label_delay_ms is not None
    if separate_labels and args.realtime is None:
        raise DatasetError("--label-rate-hz and --label-delay-ms need --realtime (lockstep maps every label on time)")
    if args.realtime is not None:
        labels = LabelStream(args.label_rate_hz, args.label_delay_ms or 0.0) if separate_labels else None
        realtime = RealtimeOptions(None if args.realtime == "stamps" else args.realtime, args.preload_mb, labels)
    viewer = start_viewer(viewer_options)
    result = run_offline(
        dataset,
        config,
        args.out,
        args.overwrite,
        provenance,
        show_progress=not args.quiet,
        realtime=realtime,
        viewer=viewer,
        truth=truth if dataset is not truth else None,
    )
    print(format_table(result.metrics))
    print(f"run folder: {args.out}")
    return 0
