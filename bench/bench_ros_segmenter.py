"""Semantic mapping live through ROS with a segmenter: frames never wait for their labels.

The README's recipe on a recorded sequence: the bag played at its recorded rate by ``bag_player``;
``segmentation_node`` (SegFormer) segments the colour stream; ``slam_node`` with
``use_semantics:=true`` tracks and maps it and fuses each label image when it comes. Alternating
with the same replay with ``use_semantics:=false`` and no segmenter. For each: frames tracked
(poses published), their ATE (camera centres after SE(3) alignment), the label images the
segmenter published and what ``slam_node`` made of them (fused, unmatched).

Without ``--model`` the segmenter is SegFormer-b0's architecture with random weights, saved to a
folder and loaded as a model would be: the real model's cost, meaningless labels (the weights cannot
be downloaded on a machine without the hub). Needs the ``segmentation`` extra (transformers).

    python bench/bench_ros_segmenter.py ../shared/data/tum_fr3_teddy --downscale 4 [--model NAME_OR_DIR]
        [--seg-downscale 2 --seg-threads 1 --seg-rate-hz 1 --slam-threads 1] [--repeats 2] [--no-append]
"""

from __future__ import annotations

import argparse
import random
import shutil
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.bench_replay_loss import REMAPS, replay
from bench.bench_ros_live import bag_of, published_ate_cm
from bench.common import append_section, markdown_table

LABELS_TOPIC = "/segmentation/labels"  # the segmenter publishes here, slam_node subscribes here
COLOR_TOPIC = next(r.split(":=")[1] for r in REMAPS if r.startswith("rgb/image:="))
HEADERS = ["run", "frames in", "tracked", "tracked %", "ATE cm", "labels published", "fused", "unmatched", "fused %"]


@dataclass
class Outcome:
    name: str
    frames_in: int
    tracked: int
    ate_cm: float | None
    published: int | None = None
    fused: int | None = None
    unmatched: int | None = None

    @property
    def fraction(self) -> float:
        return self.tracked / max(self.frames_in, 1)

    def row(self) -> list[object]:
        def count(value: int | None) -> object:
            return "-" if value is None else value

        share = "-" if not self.published or self.fused is None else f"{100 * self.fused / self.published:.0f} %"
        ate_text = "n/a" if self.ate_cm is None else f"{self.ate_cm:.2f}"
        return [
            self.name,
            self.frames_in,
            self.tracked,
            f"{100 * self.fraction:.0f} %",
            ate_text,
            count(self.published),
            count(self.fused),
            count(self.unmatched),
            share,
        ]


def random_segformer(folder: Path) -> str:
    """SegFormer-b0's architecture with random weights saved as a model folder; its path."""
    from sgs_slam_core.segmentation.segformer import Segmenter  # noqa: PLC0415 - the optional extra

    Segmenter.random("cpu").model.save_pretrained(folder)
    return str(folder)


def ros_run(bag: Path, args: argparse.Namespace, model: str | None) -> Outcome:
    """One replay; with ``model`` the segmenter runs beside ``slam_node`` and the node maps its labels."""
    from bench.pose_recorder import PoseRecorder  # noqa: PLC0415 - rclpy only for this run

    domain = random.randint(1, 100)
    params: tuple[str, ...] = ("map_alignment:=optical", f"threads:={args.slam_threads}")
    if args.set:  # core config overrides, one list parameter
        params += (f"overrides:={args.set!r}",)
    remaps = (*(r for r in REMAPS if not r.startswith("semantic/image:=")), f"semantic/image:={LABELS_TOPIC}")
    side: tuple[str, ...] = ()
    if model is not None:
        side = ("sgs_slam_ros.segmentation_node", "--transport", "shm", "--ros-args", "-p", f"model:={model}")
        side += (
            "-p",
            "device:=cpu",
            "-p",
            f"downscale:={float(args.seg_downscale)!r}",
            "-p",
            f"threads:={args.seg_threads}",
            "-p",
            f"max_rate_hz:={float(args.seg_rate_hz)!r}",
        )
        side += ("-r", f"rgb/image:={COLOR_TOPIC}", "-r", f"semantic/image:={LABELS_TOPIC}")
    with PoseRecorder(domain) as recorder:

        def node_ready() -> None:
            recorder.wait_spinning("tracking_node", 120.0)
            if model is not None:
                recorder.wait_spinning("segmentation_node", 120.0)

        counts = replay(bag, "shm", args.downscale, args.preset, model is not None, params, domain, node_ready, remaps,
                        side)  # fmt: skip
        poses = recorder.wait_quiet(5.0)
    ate_cm = published_ate_cm(bag, poses)
    if model is None:
        return Outcome("slam_node, semantics off", int(counts["frames_in"]), len(poses), ate_cm)
    return Outcome(
        "segmentation_node -> slam_node, semantics on",
        int(counts["frames_in"]),
        len(poses),
        ate_cm,
        int(counts["side_frames_segmented"]),
        int(counts["labels_fused"]),
        int(counts["labels_unmatched"]),
    )


def _median_ate(runs: list[Outcome]) -> float:
    values = [r.ate_cm for r in runs if r.ate_cm is not None]
    return float(np.median(values)) if values else float("nan")


def summary(off: list[Outcome], on: list[Outcome]) -> str:
    """Medians over the repeats and the three checks on them."""
    fraction_off, fraction_on = (float(np.median([r.fraction for r in runs])) for runs in (off, on))
    ate_off, ate_on = (_median_ate(runs) for runs in (off, on))
    fused = float(np.median([r.fused / r.published for r in on if r.published and r.fused is not None] or [np.nan]))
    return (
        f"Medians over {len(on)} repeats: semantics off {100 * fraction_off:.0f} % tracked at ATE {ate_off:.2f} cm; "
        f"with the segmenter {100 * fraction_on:.0f} % at {ate_on:.2f} cm: {100 * (fraction_on - fraction_off):+.0f} "
        f"points (target: within 5), ATE {ate_on / ate_off:.2f}x (target: at most 1.2x); {100 * fused:.0f} % of the "
        "label images published fused (target: at least 80 %)."
    )


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("input", type=Path, help="a dataset folder (converted to a bag once) or an MCAP bag")
    p.add_argument("--downscale", type=float, default=4.0, help="processing size: the input divided by this")
    p.add_argument("--preset", default="tum")
    p.add_argument("--model", help="SegFormer ADE20K hub name or folder (default: b0 with random weights)")
    p.add_argument("--seg-downscale", type=float, default=1.0, help="segmentation_node's downscale parameter")
    p.add_argument("--seg-threads", type=int, default=0, help="segmentation_node's threads parameter (0: default)")
    p.add_argument("--seg-rate-hz", type=float, default=0.0, help="segmentation_node's max_rate_hz (0: uncapped)")
    p.add_argument("--slam-threads", type=int, default=0, help="slam_node's threads parameter (0: default)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="slam_node's core config overrides")
    p.add_argument("--compress", choices=["zstd", "none"], default="zstd", help="chunks of the bag a dataset becomes")
    p.add_argument("--repeats", type=int, default=2, help="replays of each (a live run varies run to run)")
    p.add_argument("--no-append", action="store_true")
    args = p.parse_args()
    work = Path(tempfile.mkdtemp(prefix="ros-seg-"))
    try:
        model = args.model or random_segformer(work / "segformer-b0-random")
        bag = bag_of(args.input, work, args.compress)
        off, on = [], []
        for _ in range(args.repeats):  # alternating, so a slow spell of the machine hits both
            off.append(ros_run(bag, args, None))
            on.append(ros_run(bag, args, model))
            print(" | ".join(map(str, off[-1].row() + on[-1].row())), flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    rows = [x.row() for pair in zip(off, on, strict=True) for x in pair]
    text = f"{markdown_table(HEADERS, rows)}\n\n{summary(off, on)}"
    print(text)
    if not args.no_append:
        model_name = args.model or "SegFormer-b0, random weights"
        note = (
            f"`{args.input.name}`, preset {args.preset}, downscale {args.downscale:g}, segmenter {model_name} on the "
            f"CPU (its downscale {args.seg_downscale:g}, threads {args.seg_threads or 'default'}, "
            f"at most {args.seg_rate_hz or 'any'} Hz; slam_node's threads "
            f"{args.slam_threads or 'default'}); `bag_player` "
            "at the recorded rate, `segmentation_node` and `slam_node` (shared memory, three "
            "processes), alternating with semantics off"
        )
        append_section(f"Semantic mapping through ROS with a segmenter: {args.input.name}", note + "\n\n" + text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
