"""Fast motion: a hand-held sweep tracked lockstep and live, and a kidnapped camera found again.

Runs of one TUM sequence (fr1/desk is the field's standard fast one) through ``sgs-slam run``:

- **lockstep** at ``--downscale`` (every frame tracked, then mapped);
- **--realtime** at the recorded stamps (``--realtime-repeats`` times);
- **kidnap** (lockstep): the same sequence with ``--cut-s`` seconds cut out at ``--cut-at-s``, so
  the frames after the cut come from where the camera went unseen.

For each: frames, frames with a pose estimate (the camera not lost), the ATE RMSE over them (camera
centres after SE(3) alignment), tracking failures, times lost, relocalizations, frames while lost
and tracking ms per frame. The kidnap adds the frames from the cut to the first lost frame and to
the relocalization, whether any frame was mapped while lost, and the ATE of the frames after the
relocalization against the uncut lockstep run's ATE over the same frames.

    python bench/bench_fast_motion.py /path/to/tum_fr1_desk --downscale 4 [--set KEY=VALUE] [--no-append]
"""

from __future__ import annotations

import argparse
import csv
import json
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import append_section, markdown_table
from sgs_slam_core.metrics import ate
from sgs_slam_core.metrics.trajectory_io import read_tum_trajectory


@dataclass(frozen=True)
class Run:
    """One ``sgs-slam run``'s folder, read back."""

    name: str
    metrics: dict
    stamps: np.ndarray  # [T] ns
    poses: np.ndarray  # [T, 4, 4] c2w
    truth: np.ndarray  # [T, 4, 4] c2w (identity where the frame has no ground truth)
    has_truth: np.ndarray  # [T] bool
    states: list[str]  # per frame: ok, lost, relocalized
    mapped_while_lost: int  # lost frames with mapping steps or added Gaussians

    @property
    def estimated(self) -> np.ndarray:  # [T] bool
        """Frames with a pose estimate (the camera not lost)."""
        return np.array([s != "lost" for s in self.states])

    def ate_cm(self, keep: np.ndarray | None = None) -> float:
        """ATE RMSE (cm) over the estimated frames (and ``keep``)."""
        mask = self.estimated & self.has_truth if keep is None else self.estimated & self.has_truth & keep
        return 100 * ate(self.poses[mask], self.truth[mask]).rmse

    def row(self) -> list[object]:
        m = self.metrics
        n, estimated = m["frames_in"], int(self.estimated.sum())
        return [
            self.name,
            n,
            f"{estimated} ({100 * estimated / n:.0f} %)",
            f"{self.ate_cm():.2f}",
            m["tracking_failures"],
            m["tracking_lost_events"],
            m["relocalizations"],
            m["frames_while_lost"],
            f"{m['track_ms_per_frame']:.1f}",
        ]


HEADERS = ["run", "frames in", "posed (not lost)", "ATE cm", "failures", "lost", "relocalized", "frames lost",
           "tracking ms/frame"]  # fmt: skip


def sgs_run(source: Path, out: Path, args: argparse.Namespace, name: str, realtime: bool = False) -> Run:
    """``sgs-slam run`` on ``source``; its folder read back."""
    cmd = [sys.executable, "-m", "sgs_slam_core.cli", "run", str(source), "--out", str(out), "--overwrite", "--quiet"]
    cmd += ["--downscale", str(args.downscale), "--preset", "tum", *(["--realtime", "stamps"] if realtime else [])]
    for item in args.overrides:
        cmd += ["--set", item]
    proc = subprocess.run(cmd, check=False, capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"bench_fast_motion: {' '.join(cmd)} failed:\n{proc.stderr[-2000:]}")
    stamps, poses = read_tum_trajectory(out / "trajectory.txt")
    truth_stamps, truth_poses = read_tum_trajectory(out / "groundtruth.txt")  # only the frames with ground truth
    by_stamp = dict(zip(truth_stamps.tolist(), truth_poses, strict=True))
    has_truth = np.array([t in by_stamp for t in stamps.tolist()])
    truth = np.stack([by_stamp.get(t, np.eye(4)) for t in stamps.tolist()])
    with (out / "frames.csv").open() as f:
        rows = list(csv.DictReader(f))
    lost = [r for r in rows if r["tracking_state"] == "lost"]
    mapped = sum(1 for r in lost if int(r["map_iterations"]) or int(r["added"]))
    metrics = json.loads((out / "metrics.json").read_text())
    return Run(name, metrics, stamps, poses, truth, has_truth, [r["tracking_state"] for r in rows], mapped)


def cut_copy(source: Path, work: Path, at_s: float, length_s: float) -> tuple[Path, int]:
    """A copy of the TUM folder ``source`` (images linked) without the frames in [at_s, at_s + length_s).

    Returns the folder and the stamp (ns) of the first colour frame after the cut.
    """
    out = work / f"{source.name}_cut"
    out.mkdir()
    for sub in ("rgb", "depth"):
        (out / sub).symlink_to((source / sub).resolve())
    shutil.copy(source / "groundtruth.txt", out / "groundtruth.txt")
    first = None
    after = None
    for name in ("rgb.txt", "depth.txt"):
        kept = []
        for line in (source / name).read_text().splitlines():
            if line.startswith("#") or not line.strip():
                kept.append(line)
                continue
            t = float(line.split()[0])
            first = t if first is None else first
            if first + at_s <= t < first + at_s + length_s:
                continue
            if name == "rgb.txt" and t >= first + at_s + length_s and after is None:
                after = t
            kept.append(line)
        (out / name).write_text("\n".join(kept) + "\n")
    if after is None:
        raise SystemExit(f"bench_fast_motion: nothing left after a cut at {at_s} s")
    return out, round(after * 1e9)


def kidnap_report(cut: Run, whole: Run, return_ns: int) -> str:
    """The kidnap's checks: lost within 3 frames, found within 30, ATE after it, nothing mapped while lost."""
    back = int(np.searchsorted(cut.stamps, return_ns - 1_000_000))  # first frame after the cut (stamps rounded)
    lost = next((i for i in range(back, len(cut.states)) if cut.states[i] == "lost"), None)
    found = next((i for i in range(back, len(cut.states)) if cut.states[i] == "relocalized"), None)
    lines = [f"Cut: frames resume at index {back} of {len(cut.states)}."]
    if lost is None or found is None:
        return " ".join([*lines, f"Lost at {lost}, relocalized at {found}: the checks cannot be made."])
    after = np.arange(len(cut.states)) > found
    common = np.isin(whole.stamps, cut.stamps[after])
    ratio = cut.ate_cm(after) / whole.ate_cm(common)
    lines += [
        f"Lost {lost - back} frames after the return (target: within 3),",
        f"relocalized {found - back} frames after it (target: within 30);",
        f"ATE of the {int(after.sum())} frames after the relocalization {cut.ate_cm(after):.2f} cm against",
        f"{whole.ate_cm(common):.2f} cm for the same frames uncut ({ratio:.2f}x; target: at most 1.5x);",
        f"frames mapped while lost: {cut.mapped_while_lost} (target: 0).",
    ]
    return " ".join(lines)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("input", type=Path, help="a TUM RGB-D sequence folder")
    p.add_argument("--downscale", type=float, default=4)
    p.add_argument("--realtime-repeats", type=int, default=1, help="--realtime runs (0: none)")
    p.add_argument("--cut-at-s", type=float, default=8.0, help="kidnap: where the cut starts (s into the sequence)")
    p.add_argument("--cut-s", type=float, default=2.0, help="kidnap: seconds cut out (0: no kidnap run)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    p.add_argument("--no-append", action="store_true", help="print only; do not append to BENCHMARKS.md")
    args = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        runs = [sgs_run(args.input, work / "lockstep", args, "lockstep")]
        for i in range(args.realtime_repeats):
            runs.append(sgs_run(args.input, work / f"realtime{i}", args, "--realtime (recorded stamps)", True))
        note = ""
        if args.cut_s > 0:
            folder, return_ns = cut_copy(args.input, work, args.cut_at_s, args.cut_s)
            cut = sgs_run(folder, work / "kidnap", args, f"kidnap: {args.cut_s:g} s cut at {args.cut_at_s:g} s")
            runs.append(cut)
            note = kidnap_report(cut, runs[0], return_ns)
    size = f"{round(640 / args.downscale)}x{round(480 / args.downscale)}"
    body = markdown_table(HEADERS, [r.row() for r in runs]) + ("\n\n" + note if note else "")
    print(body)
    if not args.no_append:
        append_section(f"Fast motion: {args.input.name} {size}", body)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
