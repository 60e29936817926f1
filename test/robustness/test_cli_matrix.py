"""The robustness matrix: one row per user mistake or broken environment, with its exact outcome.

Each row builds its broken input in a fresh tmp folder, runs the command in-process and checks
the exit code, that stderr has no traceback and ends in exactly one line from the tool naming the
problem, which files exist (and are complete) or are absent afterwards, and that no temporary file
is left behind. Add a row for every bug found.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import pytest
import yaml

from bags.cli import main as bag_main
from sgs_slam_core.cli import main as slam_main
from sgs_slam_core.mapio import load_map, read_splat_ply
from sgs_slam_core.metrics import read_tum_trajectory

from .fakefs import FullDisk, make_read_only
from .inputs import (
    FAST_RUN,
    Env,
    bag_with_label_65535,
    bag_with_metadata,
    map_with_unknown_labels,
    ply_with_header,
    ply_with_nan,
    replica_non_rigid,
    replica_with,
    run_with_metrics,
    run_with_yaml,
    scannet_tiny,
    sgsmap_with,
    tum_from_tiny,
    tum_latin1,
)

pytestmark = pytest.mark.slow  # end to end: left out of make test-fast

Patch = Callable[[Env, pytest.MonkeyPatch], None]
# what a read-only folder says: root ignores permissions, so there it is faked as a read-only mount
READ_ONLY = "Read-only file system" if os.geteuid() == 0 else "Permission denied"


@dataclass(frozen=True)
class Case:
    """A broken input or environment and what must come of it."""

    id: str
    argv: Callable[[Env], list[str]]
    code: int
    message: str = ""  # fragment of the tool's one error line
    exists: tuple[str, ...] = ()  # under env.tmp, complete (decodable) afterwards
    absent: tuple[str, ...] = ()  # under env.tmp, absent afterwards
    fs: Patch | None = None  # a failing file system or function, installed before the command
    check: Callable[[Env], None] | None = None  # further assertions on the outputs
    tool: str = "sgs-slam"


def read_only(folder: str) -> Patch:
    def install(env: Env, mp: pytest.MonkeyPatch) -> None:
        make_read_only(env.tmp / folder, mp)

    return install


def full_disk(budget: int) -> Patch:
    def install(env: Env, mp: pytest.MonkeyPatch) -> None:
        FullDisk(mp, budget)

    return install


def failing(target: str, error: BaseException) -> Patch:
    def install(env: Env, mp: pytest.MonkeyPatch) -> None:
        def fail(*args: object, **kwargs: object) -> None:
            raise error

        mp.setattr(target, fail)

    return install


def lpips_weights(content: bytes) -> Patch:
    def install(env: Env, mp: pytest.MonkeyPatch) -> None:
        (env.tmp / "w.pth").write_bytes(content)
        mp.setenv("SGS_SLAM_LPIPS_ALEXNET", str(env.tmp / "w.pth"))
        mp.setenv("SGS_SLAM_LPIPS_LINEAR", str(env.tmp / "w.pth"))

    return install


def convert_fails_midway(env: Env, mp: pytest.MonkeyPatch) -> None:
    """The bag writer runs out of disk after writing part of the bag."""
    import bags.cli

    def convert(dataset: object, out: Path, *args: object, **kwargs: object) -> None:
        out.mkdir()
        (out / "b_0.mcap").write_bytes(b"\x89MCAP0\r\n partial")
        raise OSError(28, "No space left on device", str(out / "b_0.mcap"))

    mp.setattr(bags.cli, "convert", convert)


def run_tiny(out: str, *extra: str) -> Callable[[Env], list[str]]:
    return lambda env: ["run", str(env.tiny), "--out", env.path(out), *FAST_RUN, *extra]


def run_yaml(env: Env, key: str) -> dict:
    return yaml.safe_load((env.tmp / key / "run.yaml").read_text())


def metrics(env: Env, key: str) -> dict:
    return json.loads((env.tmp / key / "metrics.json").read_text())


def check_run_statuses(folder: str, status: str, **values: object) -> Callable[[Env], None]:
    def check(env: Env) -> None:
        info = run_yaml(env, folder)
        assert info["status"] == status, info
        for key, value in values.items():
            assert info[key] == value, (key, info)

    return check


# fmt: off
CASES = [
    # ------------------------------------------------------------------ outputs: read-only folders
    Case("run-out-read-only", run_tiny("ro/run"), 1, READ_ONLY, absent=("ro/run",),
         fs=read_only("ro")),
    Case("edit-out-read-only", lambda e: ["edit", str(e.run / "map.sgsmap"), "--remove-label", "1", "--out",
         e.path("ro/e.sgsmap")], 1, "ro/e.sgsmap: " + READ_ONLY, absent=("ro/e.sgsmap",),
         fs=read_only("ro")),
    Case("export-out-read-only", lambda e: ["export", str(e.run / "map.sgsmap"), "--out", e.path("ro/e.ply")],
         1, "ro/e.ply: " + READ_ONLY, absent=("ro/e.ply",), fs=read_only("ro")),
    Case("render-out-read-only", lambda e: ["render", str(e.run / "map.sgsmap"), "--orbit", "2", "--out",
         e.path("ro/views")], 1, "ro/views: " + READ_ONLY, absent=("ro/views",), fs=read_only("ro")),
    Case("synth-out-read-only", lambda e: ["synth", e.path("ro/s"), "--preset", "tiny", "--frames", "2"], 1,
         READ_ONLY, absent=("ro/s",), fs=read_only("ro")),
    # ------------------------------------------------------------------ outputs: a full disk
    Case("run-disk-full-at-the-map", run_tiny("full"), 1, "full/map.sgsmap: No space left on device",
         exists=("full/trajectory.txt", "full/frames.csv", "full/config.yaml", "full/run.yaml"),
         absent=("full/map.sgsmap", "full/map.ply", "full/metrics.json"), fs=full_disk(20_000),
         check=check_run_statuses("full", "failed")),
    Case("run-disk-full-at-the-start", run_tiny("full"), 1, "No space left on device", absent=("full",),
         fs=full_disk(100)),
    Case("synth-disk-full", lambda e: ["synth", e.path("s"), "--preset", "tiny"], 1, "No space left on device",
         absent=("s",), fs=full_disk(30_000)),
    Case("synth-overwrite-disk-full", lambda e: ["synth", str(e.copy(e.tiny, "s")), "--preset", "tiny",
         "--overwrite"], 1, "No space left on device", absent=("s",), fs=full_disk(30_000)),
    Case("render-disk-full", lambda e: ["render", str(e.run / "map.sgsmap"), "--orbit", "8", "--out", e.path("v")],
         1, "No space left on device", exists=("v",), fs=full_disk(15_000)),
    Case("export-disk-full", lambda e: ["export", str(e.run / "map.sgsmap"), "--out", e.path("x.ply")], 1,
         "x.ply: No space left on device", absent=("x.ply",), fs=full_disk(10_000)),
    Case("edit-disk-full", lambda e: ["edit", str(e.run / "map.sgsmap"), "--remove-label", "1", "--out",
         e.path("x.sgsmap")], 1, "x.sgsmap: No space left on device", absent=("x.sgsmap",), fs=full_disk(10_000)),
    Case("render-out-is-a-file", lambda e: ["render", str(e.run / "map.sgsmap"), "--orbit", "2", "--out",
         str(Path(e.copy(e.run / "run.yaml", "taken")))], 1, "exists and is not a folder", exists=("taken",)),
    Case("run-out-is-a-file", lambda e: ["run", str(e.tiny), "--out", str(e.copy(e.run / "run.yaml", "taken")),
         *FAST_RUN], 1, "exists and is a file", exists=("taken",)),
    Case("run-out-is-a-file-even-with-overwrite", lambda e: ["run", str(e.tiny), "--out",
         str(e.copy(e.run / "run.yaml", "taken")), "--overwrite", *FAST_RUN], 1, "exists and is a file",
         exists=("taken",)),
    # ------------------------------------------------------------------ a run lost at its very end
    Case("bag-label-65535-is-evaluated", lambda e: ["run", str(bag_with_label_65535(e)), "--out", e.path("r"),
         *FAST_RUN], 0, exists=("r/metrics.json", "r/map.sgsmap", "r/trajectory.txt"),
         check=lambda e: metrics(e, "r")["miou"] is not None and check_run_statuses("r", "complete")(e)),
    Case("evaluation-out-of-memory-keeps-the-run", run_tiny("r"), 1, "evaluation failed: MemoryError",
         exists=("r/trajectory.txt", "r/map.sgsmap", "r/map.ply", "r/frames.csv", "r/metrics.json"),
         fs=failing("sgs_slam_core.runner.offline.evaluate", MemoryError("cannot allocate 32 GiB")),
         check=lambda e: metrics(e, "r")["evaluation_error"] and check_run_statuses("r", "evaluation_failed")(e)),
    Case("evaluation-bug-keeps-the-run", run_tiny("r"), 1, "evaluation failed: KeyError: 101",
         exists=("r/trajectory.txt", "r/map.sgsmap", "r/metrics.json"),
         fs=failing("sgs_slam_core.runner.offline.evaluate", KeyError(101))),
    # ------------------------------------------------------------------ sizes: usage errors before any work
    Case("synth-huge", lambda e: ["synth", e.path("s"), "--width", "100000", "--height", "100000"], 2,
         "--width: 100000 is out of range: 8..4096", absent=("s",)),
    Case("synth-too-many-pixels", lambda e: ["synth", e.path("s"), "--width", "4000", "--height", "4000"], 2,
         "at most 4,194,304", absent=("s",)),
    Case("synth-seed-negative", lambda e: ["synth", e.path("s"), "--seed", "-1"], 2,
         "--seed: -1 is out of range: 0..4294967295", absent=("s",)),
    Case("synth-holes-not-a-fraction", lambda e: ["synth", e.path("s"), "--depth-holes", "1.5"], 2,
         "--depth-holes: 1.5 is out of range: [0, 1)", absent=("s",)),
    Case("synth-frames-zero", lambda e: ["synth", e.path("s"), "--frames", "0"], 2, "--frames: 0 is out of range"),
    Case("render-huge", lambda e: ["render", str(e.run / "map.sgsmap"), "--orbit", "1", "--width", "100000",
         "--out", e.path("v")], 2, "--width: 100000 is out of range: 1..4096", absent=("v",)),
    Case("render-width-zero", lambda e: ["render", str(e.run / "map.sgsmap"), "--orbit", "1", "--width", "0",
         "--out", e.path("v")], 2, "--width: 0 is out of range", absent=("v",)),
    Case("render-derived-height-too-big", lambda e: ["render", str(e.run / "map.sgsmap"), "--orbit", "1",
         "--height", "4000", "--out", e.path("v")], 2, "views would be 5333x4000 px", absent=("v",)),
    Case("render-orbit-zero", lambda e: ["render", str(e.run / "map.sgsmap"), "--orbit", "0", "--out",
         e.path("v")], 2, "--orbit: 0 is out of range"),
    Case("render-radius-nan", lambda e: ["render", str(e.run / "map.sgsmap"), "--orbit", "2", "--radius", "nan",
         "--out", e.path("v")], 2, "--radius: nan is out of range"),
    Case("run-max-frames-zero", lambda e: ["run", str(e.tiny), "--out", e.path("r"), "--max-frames", "0"], 2,
         "--max-frames: 0 is out of range: >= 1", absent=("r",)),
    Case("run-downscale-below-one", lambda e: ["run", str(e.tiny), "--out", e.path("r"), "--downscale", "0.5"], 2,
         "--downscale: 0.5 is out of range: [1, 64]", absent=("r",)),
    Case("export-opacity-above-one", lambda e: ["export", str(e.run / "map.sgsmap"), "--points", "--min-opacity",
         "2", "--out", e.path("p.ply")], 2, "--min-opacity: 2 is out of range: [0, 1]"),
    Case("edit-translate-inf", lambda e: ["edit", str(e.run / "map.sgsmap"), "--move-label", "1", "--translate",
         "inf", "0", "0", "--out", e.path("m.sgsmap")], 2, "--translate: inf is out of range"),
    Case("bag-convert-max-frames-zero", lambda e: ["convert", str(e.tiny), "--out", e.path("b"), "--max-frames",
         "0"], 2, "--max-frames: 0 is out of range", absent=("b",), tool="sgs-slam-bag"),
    # ------------------------------------------------------------------ dataset files
    Case("tum-groundtruth-garbage", lambda e: ["run", str(tum_with(e, "groundtruth.txt",
         "# gt\n1.0 abc 0 0 0 0 0 1\n")), "--out", e.path("r"), *FAST_RUN], 1,
         "groundtruth.txt:2: tx 'abc' is not a finite number", absent=("r",)),
    Case("tum-groundtruth-binary", lambda e: ["run", str(tum_with(e, "groundtruth.txt",
         b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR" + bytes(range(256)))), "--out", e.path("r"), *FAST_RUN], 1,
         "groundtruth.txt is a binary file", absent=("r",)),
    Case("tum-groundtruth-zero-quaternion", lambda e: ["run", str(tum_with(e, "groundtruth.txt",
         "1.0 0 0 0 0 0 0 0\n")), "--out", e.path("r"), *FAST_RUN], 1,
         "groundtruth.txt:1: quaternion (qx qy qz qw) is zero", absent=("r",)),
    Case("tum-rgb-list-latin1-works", lambda e: ["run", str(tum_latin1(e)), "--out", e.path("r"), *FAST_RUN], 0,
         exists=("r/trajectory.txt", "r/metrics.json"),
         check=lambda e: len(read_tum_trajectory(e.tmp / "r" / "trajectory.txt")[0]) == 3),
    Case("tum-rgb-list-missing-column", lambda e: ["run", str(tum_with(e, "rgb.txt", "1.0\n")), "--out",
         e.path("r"), *FAST_RUN], 1, "rgb.txt:1: expected 2 columns, got 1"),
    Case("replica-traj-non-rigid", lambda e: ["run", str(replica_non_rigid(e)), "--out", e.path("r"), *FAST_RUN],
         1, "traj.txt: pose 3: not a rigid transform", absent=("r",)),
    Case("replica-traj-text", lambda e: ["run", str(replica_with(e, "t", "traj.txt", "hello world\n")), "--out",
         e.path("r"), *FAST_RUN], 1, "traj.txt:1: not a number", absent=("r",)),
    Case("replica-camera-yaml-string", lambda e: ["run", str(replica_with(e, "c", "camera.yaml",
         "width: 64\nheight: 48\nfx: abc\nfy: 48\ncx: 31.5\ncy: 23.5\n")), "--out", e.path("r"), *FAST_RUN], 1,
         "camera.yaml: fx: expected a number, got 'abc'", absent=("r",)),
    Case("replica-camera-yaml-fractional-width", lambda e: ["run", str(replica_with(e, "c", "camera.yaml",
         "width: 64.5\nheight: 48\nfx: 48\nfy: 48\ncx: 31.5\ncy: 23.5\n")), "--out", e.path("r"), *FAST_RUN], 1,
         "camera.yaml: width: expected an integer, got 64.5"),
    Case("replica-labels-yaml-garbage", lambda e: ["run", str(replica_with(e, "l", "labels.yaml",
         "classes: [{id: one, name: x, color: [1, 2]}]\n")), "--out", e.path("r"), *FAST_RUN], 1,
         "bad label table", absent=("r",)),
    Case("replica-corrupt-frame-is-skipped", lambda e: ["run", str(replica_with(e, "p", "frames/frame000001.png",
         b"not a png")), "--out", e.path("r"), *FAST_RUN], 0, exists=("r/trajectory.txt", "r/metrics.json"),
         check=lambda e: metrics(e, "r")["bad_frames"] == 1 and metrics(e, "r")["frames"] == 2),
    Case("scannet-tsv-id-beyond-16-bit", lambda e: ["run", str(scannet_tiny(e, tsv=b"id\tnyu40id\n1000000000000\t5\n")),
         "--out", e.path("r"), *FAST_RUN], 1, "id: must be in 0..65535, got 1000000000000", absent=("r",)),
    Case("scannet-tsv-latin1", lambda e: ["convert", str(scannet_tiny(e,
         tsv="id\tnyu40id\tcategory\n1\t1\tchaise d\xe9pli\xe9e\n".encode("latin-1"))), "--out", e.path("b")], 0,
         exists=("b",), tool="sgs-slam-bag"),
    Case("scannet-pose-non-rigid", lambda e: ["run", str(scannet_tiny(e, pose_1="1 0 0 0\n0 1 0 0\n0 0 5 0\n"
         "0 0 0 1\n")), "--out", e.path("r"), *FAST_RUN], 1, "1.txt: not a rigid transform", absent=("r",)),
    Case("scannet-pose-ragged", lambda e: ["run", str(scannet_tiny(e, pose_1="1 0 0\n0 1 0 0\n")), "--out",
         e.path("r"), *FAST_RUN], 1, "1.txt must hold a 4x4 matrix", absent=("r",)),
    Case("scannet-intrinsics-zero-focal", lambda e: ["run", str(scannet_tiny(e, intrinsic="0 0 0 0\n" * 4)), "--out",
         e.path("r"), *FAST_RUN], 1, "focal lengths must be positive", absent=("r",)),
    Case("config-file-binary", lambda e: ["run", str(e.tiny), "--config", str(e.copy(e.run / "map.sgsmap", "c.yaml")),
         "--out", e.path("r"), *FAST_RUN], 1, "c.yaml is a binary file", absent=("r",)),
    Case("bag-depth-units-abc", lambda e: ["run", str(bag_with_metadata(e, "b", depth_units_per_metre="abc")),
         "--out", e.path("r"), *FAST_RUN], 1, "depth_units_per_metre: expected a number, got 'abc'", absent=("r",)),
    Case("bag-depth-scale-abc", lambda e: ["run", str(bag_with_metadata(e, "b", depth_scale="abc")), "--out",
         e.path("r"), *FAST_RUN], 1, "depth_scale: expected a number, got 'abc'", absent=("r",)),
    Case("bag-depth-scale-negative", lambda e: ["run", str(bag_with_metadata(e, "b", depth_scale="-5")), "--out",
         e.path("r"), *FAST_RUN], 1, "depth_scale: must be > 0, got -5"),
    Case("bag-extra-metadata-key-works", lambda e: ["run", str(bag_with_metadata(e, "b", preset="synthetic")),
         "--out", e.path("r"), *FAST_RUN], 0, exists=("r/trajectory.txt",)),
    Case("bag-label-table-garbage", lambda e: ["run", str(bag_with_metadata(e, "b", label_table="[1, 2")), "--out",
         e.path("r"), *FAST_RUN], 1, "label_table", absent=("r",)),
    Case("bag-info-label-table-garbage", lambda e: ["info", str(bag_with_metadata(e, "b", label_table="{\"x\": 1}"))],
         0, tool="sgs-slam-bag"),
    Case("bag-metadata-not-yaml", lambda e: ["run", str(replica_with_file(e.copy(e.bag, "b"), "metadata.yaml",
         "rosbag2_bagfile_information: [unclosed\n")), "--out", e.path("r"), *FAST_RUN], 1,
         "not valid rosbag2 metadata"),
    # ------------------------------------------------------------------ run folders
    Case("eval-run-yaml-corrupt", lambda e: ["eval", str(run_with_yaml(e, "r", "input: [unclosed\n"))], 1,
         "run.yaml is not valid YAML"),
    Case("eval-run-yaml-list", lambda e: ["eval", str(run_with_yaml(e, "r", "- 1\n- 2\n"))], 1,
         "run.yaml: expected a mapping"),
    Case("eval-run-yaml-unknown-option", lambda e: ["eval", str(run_with_yaml(e, "r", options={"start": 0,
         "frobnicate": 3}))], 1, "options: unknown keys ['frobnicate']"),
    Case("eval-run-yaml-option-type", lambda e: ["eval", str(run_with_yaml(e, "r", options={"stride": "abc"}))], 1,
         "options.stride: expected an integer, got 'abc'"),
    Case("run-viewer-port-zero", lambda e: ["run", str(e.tiny), "--viewer-save", e.path("v.rrd"), "--viewer-port",
         "0", "--out", e.path("r")], 2, "--viewer-port: 0 is out of range: 1..65535", absent=("r",)),
    Case("compare-metrics-json-list", lambda e: ["compare", str(run_with_metrics(e, "r", "[1, 2]\n"))], 1,
         "expected a JSON object, got list"),
    Case("compare-run-yaml-list", lambda e: ["compare", str(run_with_yaml(e, "r", "- 1\n- 2\n"))], 1,
         "run.yaml: expected a mapping, got list"),
    Case("compare-run-yaml-corrupt", lambda e: ["compare", str(run_with_yaml(e, "r", "input: [unclosed\n"))], 1,
         "run.yaml is not valid YAML"),
    Case("eval-run-yaml-binary", lambda e: ["eval", str(run_with_yaml(e, "r", "\x00\x01\x02"))], 1,
         "run.yaml is a binary file"),
    Case("eval-input-has-fewer-frames", lambda e: ["eval", str(run_with_yaml(e, "r", options={"max_frames": 2}))],
         1, "refers to frame 2, but"),
    Case("eval-no-map", lambda e: ["eval", str(without(e.copy(e.run, "r"), "map.sgsmap"))], 1,
         "has no map.sgsmap to evaluate (run.yaml: complete)"),
    Case("eval-metrics-json-corrupt-is-replaced", lambda e: ["eval", str(replica_with_file(e.copy(e.run, "r"),
         "metrics.json", "{not json"))], 0, exists=("r/metrics.json",)),
    # ------------------------------------------------------------------ map files
    Case("ply-vertex-count-string", lambda e: ["labels", str(ply_with_header(e, "a.ply", "element vertex",
         "element vertex abc\ncomment"))], 1, "vertex count: expected an integer"),
    Case("ply-vertex-count-negative", lambda e: ["labels", str(ply_with_header(e, "a.ply", "element vertex",
         "element vertex -5\ncomment"))], 1, "vertex count: must be in 0.., got -5"),
    Case("ply-duplicate-property", lambda e: ["labels", str(ply_with_header(e, "a.ply", "property float y",
         "property float x"))], 1, "property 'x' appears twice"),
    Case("ply-short-property", lambda e: ["labels", str(ply_with_header(e, "a.ply", "property float y",
         "property float"))], 1, "unsupported property 'float'"),
    Case("ply-property-type-string", lambda e: ["export", str(ply_with_header(e, "a.ply", "property float y",
         "property banana y")), "--out", e.path("o.ply")], 1, "unsupported property 'banana y'", absent=("o.ply",)),
    Case("ply-label-table-not-json", lambda e: ["labels", str(ply_with_header(e, "a.ply", "comment sgs_slam_labels",
         "comment sgs_slam_labels {oops"))], 1, "the label table in the header is malformed"),
    Case("ply-nan-mean", lambda e: ["render", str(ply_with_nan(e)), "--orbit", "1", "--out", e.path("v")], 1,
         "property 'x' holds 1 NaN or infinite values", absent=("v",)),
    Case("ply-face-element-first", lambda e: ["labels", str(ply_with_header(e, "a.ply", "element vertex",
         "element face 0\nelement vertex"))], 1, "the first element is 'face'"),
    Case("sgsmap-radius-string", lambda e: ["labels", str(sgsmap_with(e, "a.sgsmap", scene_radius="abc"))], 1,
         "scene_radius: expected a number, got 'abc'"),
    Case("sgsmap-config-string", lambda e: ["render", str(sgsmap_with(e, "a.sgsmap", config="abc")), "--orbit", "1",
         "--out", e.path("v")], 1, "config must be a mapping", absent=("v",)),
    Case("sgsmap-frames-string", lambda e: ["labels", str(sgsmap_with(e, "a.sgsmap", frames_processed="x"))], 1,
         "frames_processed: expected an integer"),
    Case("sgsmap-truncated", lambda e: ["labels", str(truncated(e.copy(e.run / "map.sgsmap", "t.sgsmap")))], 1,
         "truncated or not a map"),
    Case("sgsmap-label-table-entry", lambda e: ["labels", str(sgsmap_with(e, "a.sgsmap", label_table={
         "classes": [{"id": "x", "name": "a", "color": [1, 2, 3]}]}))], 1, "malformed label table: class 0"),
    Case("map-unknown-labels-listed", lambda e: ["labels", str(map_with_unknown_labels(e, ".sgsmap"))], 0),
    Case("map-unknown-labels-rendered", lambda e: ["render", str(map_with_unknown_labels(e, ".ply")), "--orbit",
         "2", "--semantic", "--out", e.path("v")], 0, exists=("v/semantic_00001.png",)),
    Case("map-unknown-labels-exported", lambda e: ["export", str(map_with_unknown_labels(e, ".ply")), "--points",
         "--semantic", "--out", e.path("p.ply")], 0, exists=("p.ply",)),
    Case("map-unknown-labels-edited", lambda e: ["edit", str(map_with_unknown_labels(e, ".sgsmap")),
         "--remove-label", "101", "--out", e.path("x.sgsmap")], 0, exists=("x.sgsmap",),
         check=lambda e: 101 not in load_map(e.tmp / "x.sgsmap").gaussians.labels.tolist()),
    Case("edit-unknown-class-name", lambda e: ["edit", str(e.run / "map.sgsmap"), "--remove-label", "unicorn",
         "--out", e.path("x.sgsmap")], 1, "unknown class name 'unicorn'", absent=("x.sgsmap",)),
    Case("edit-out-wrong-suffix", lambda e: ["edit", str(e.run / "map.sgsmap"), "--remove-label", "1", "--out",
         e.path("x.obj")], 1, "x.obj: map files end in .sgsmap or .ply", absent=("x.obj",)),
    Case("render-c2w-binary", lambda e: ["render", str(e.run / "map.sgsmap"), "--c2w", str(text(e, "c.txt",
         "1 0 0 0\x00")), "--out", e.path("v")], 1, "c.txt is a binary file (byte 7 is NUL)", absent=("v",)),
    Case("render-c2w-huge", lambda e: ["render", str(e.run / "map.sgsmap"), "--c2w", str(e.run / "map.sgsmap"),
         "--out", e.path("v")], 1, "a text file of at most 65,536 bytes is expected", absent=("v",)),
    Case("render-c2w-not-rigid", lambda e: ["render", str(e.run / "map.sgsmap"), "--c2w", str(text(e, "c.txt",
         "2 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1")), "--out", e.path("v")], 1, "is not a rotation", absent=("v",)),
    Case("render-trajectory-zero-quaternion", lambda e: ["render", str(e.run / "map.sgsmap"), "--trajectory",
         str(text(e, "t.txt", "1.0 0 0 0 0 0 0 0\n")), "--out", e.path("v")], 1,
         "t.txt:1: quaternion (qx qy qz qw) is zero", absent=("v",)),
    Case("render-trajectory-binary", lambda e: ["render", str(e.run / "map.sgsmap"), "--trajectory",
         str(e.run / "map.sgsmap"), "--out", e.path("v")], 1, "is a binary file", absent=("v",)),
    Case("lpips-weights-garbage", run_tiny("r"), 0, exists=("r/metrics.json",), fs=lpips_weights(b"\x00garbage"),
         check=lambda e: "LPIPS weights could not be loaded" in metrics(e, "r")["lpips_note"]),
    Case("bag-convert-read-only", lambda e: ["convert", str(e.tiny), "--out", e.path("ro/b"), "--max-frames", "2"],
         1, READ_ONLY, absent=("ro/b",), fs=read_only("ro"), tool="sgs-slam-bag"),
    Case("bag-convert-disk-full-removes-the-partial-bag", lambda e: ["convert", str(e.tiny), "--out", e.path("b"),
         "--max-frames", "2"], 1, "No space left on device", absent=("b",), fs=convert_fails_midway,
         tool="sgs-slam-bag"),
    # ------------------------------------------------------------------ what is not the user's fault
    Case("internal-error-is-one-line-asking-for-a-report", lambda e: ["labels", str(e.run / "map.sgsmap")], 70,
         "internal error: TypeError: boom -- this is a bug, please report it",
         fs=failing("sgs_slam_core.cli.map_labels.label_summary", TypeError("boom"))),
    Case("out-of-memory-is-one-line", lambda e: ["labels", str(e.run / "map.sgsmap")], 1,
         "out of memory (MemoryError", fs=failing("sgs_slam_core.cli.map_labels.label_summary", MemoryError())),
    Case("os-error-from-a-library-is-one-line", lambda e: ["labels", str(e.run / "map.sgsmap")], 1,
         "/dev/sda: Input/output error",
         fs=failing("sgs_slam_core.cli.map_labels.label_summary", OSError(5, "Input/output error", "/dev/sda"))),
]
# fmt: on


def tum_with(env: Env, file: str, content: str | bytes) -> Path:
    """A tiny TUM folder with ``file`` replaced by ``content``."""
    return replica_with_file(tum_from_tiny(env), file, content)


def replica_with_file(root: Path, file: str, content: str | bytes) -> Path:
    (root / file).write_bytes(content if isinstance(content, bytes) else content.encode())
    return root


def without(root: Path, file: str) -> Path:
    (root / file).unlink()
    return root


def truncated(path: Path) -> Path:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    return path


def text(env: Env, name: str, content: str) -> Path:
    (env.tmp / name).write_text(content)
    return env.tmp / name


def run_tool(tool: str, argv: list[str]) -> int:
    try:
        return (slam_main if tool == "sgs-slam" else bag_main)(argv)
    except SystemExit as exit_:  # argparse's usage errors
        return int(exit_.code or 0)


def assert_complete(path: Path) -> None:
    """An output that exists must be whole: it decodes as what its suffix says."""
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    for f in files:
        assert f.stat().st_size > 0, f
        if f.suffix == ".png":
            assert cv2.imread(str(f), cv2.IMREAD_UNCHANGED) is not None, f
        elif f.suffix in (".yaml",):
            yaml.safe_load(f.read_text())
        elif f.suffix == ".json":
            json.loads(f.read_text())
        elif f.suffix == ".sgsmap":
            load_map(f)
        elif f.suffix == ".ply" and "sgs_slam point cloud" not in f.read_bytes()[:200].decode("ascii", "replace"):
            read_splat_ply(f)
        elif f.name == "trajectory.txt":
            read_tum_trajectory(f)


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_robustness(case: Case, env: Env, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture) -> None:
    argv = case.argv(env)
    capsys.readouterr()  # building the input may print
    if case.fs is not None:
        case.fs(env, monkeypatch)
    code = run_tool(case.tool, argv)
    monkeypatch.undo()  # the checks below read files normally
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    assert code == case.code, f"exit {code}, expected {case.code}; stderr:\n{err}"
    if code != 0:
        lines = [ln for ln in err.strip().splitlines() if ln.strip()]
        from_tool = [ln for ln in lines if ln.startswith((f"{case.tool}:", f"{case.tool} "))]
        assert len(from_tool) == 1 and lines[-1] == from_tool[0], f"not one final line:\n{err}"
        assert case.message in lines[-1], f"{case.message!r} not in {lines[-1]!r}"
    for name in case.exists:
        assert (env.tmp / name).exists(), f"{name} missing; stderr:\n{err}"
        assert_complete(env.tmp / name)
    for name in case.absent:
        assert not (env.tmp / name).exists(), f"{name} left behind: {sorted((env.tmp / name).rglob('*'))}"
    leftovers = list(env.tmp.rglob(".*.tmp"))
    assert not leftovers, f"temporary files left: {leftovers}"
    if case.check is not None:
        assert case.check(env) is not False
