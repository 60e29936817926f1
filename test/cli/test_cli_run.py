"""``sgs-slam run`` / ``eval`` / ``synth`` end to end on the tiny scene."""

import json
import subprocess
import sys

import cv2
import numpy as np
import pytest
import yaml

from sgs_slam_core.cli import main
from sgs_slam_core.mapio import load_map, read_splat_ply
from sgs_slam_core.metrics import read_tum_trajectory

from ..conftest import FAST_SLAM

pytestmark = pytest.mark.slow  # end to end: left out of make test-fast

KEYS = ("frames", "ate_rmse_m", "ate_mean_m", "psnr_db", "ssim", "depth_l1_m", "miou", "miou_paper", "fps",
        "track_ms_per_frame", "map_ms_per_frame", "num_gaussians", "peak_memory_mb", "tracking_failures", "gaussian_mb",
        "keyframes", "keyframe_mb", "keyframes_evicted")  # fmt: skip


@pytest.fixture(scope="module")
def run_dir(tiny_scene, tmp_path_factory):
    out = tmp_path_factory.mktemp("runs") / "tiny"
    sets = [a for o in FAST_SLAM for a in ("--set", o)]
    assert main(["run", str(tiny_scene), "--out", str(out), "--max-frames", "8", "--quiet", *sets]) == 0
    return out


def test_run_writes_the_documented_outputs(run_dir, capsys):
    for name in (
        "trajectory.txt",
        "metrics.json",
        "config.yaml",
        "map.ply",
        "map.sgsmap",
        "trajectory.png",
        "run.yaml",
        "frames.csv",
    ):
        assert (run_dir / name).is_file(), name
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert all(k in metrics for k in KEYS)
    assert metrics["frames"] == 8 and metrics["ate_rmse_m"] < 0.02 and metrics["psnr_db"] > 25
    assert metrics["map_steps_per_frame"] == 15  # lockstep: every mapped frame gets mapping.iterations
    assert metrics["lpips"] is None and "LPIPS" in metrics["lpips_note"]
    stamps, poses = read_tum_trajectory(run_dir / "trajectory.txt")
    assert len(stamps) == 8 and poses.shape == (8, 4, 4)
    assert yaml.safe_load((run_dir / "config.yaml").read_text())["tracking"]["adam"]["iterations"] == 30
    renders = sorted((run_dir / "renders").glob("*.png"))
    assert renders and cv2.imread(str(renders[0])).shape[0] >= 2 * 48
    saved = load_map(run_dir / "map.sgsmap")
    ply, table = read_splat_ply(run_dir / "map.ply")
    assert len(ply) == len(saved.gaussians) == metrics["num_gaussians"] and table is not None


def test_eval_recomputes_the_same_numbers(run_dir, capsys):
    before = json.loads((run_dir / "metrics.json").read_text())
    assert main(["eval", str(run_dir), "--no-write"]) == 0
    table = capsys.readouterr().out
    assert f"{before['psnr_db']:.2f}" in table and f"{100 * before['miou']:.2f}" in table
    assert f"{100 * before['ate_rmse_m']:.3f}" in table


def test_existing_output_is_refused_with_one_line(run_dir, tiny_scene):
    cmd = [
        sys.executable,
        "-m",
        "sgs_slam_core.cli",
        "run",
        str(tiny_scene),
        "--out",
        str(run_dir),
        "--max-frames",
        "2",
    ]
    out = subprocess.run(cmd, capture_output=True, text=True, check=False)
    assert out.returncode == 1
    assert out.stderr.strip().splitlines() == [out.stderr.strip().splitlines()[-1]]
    assert "exists and is not empty" in out.stderr and "--overwrite" in out.stderr


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["run", "/nonexistent/folder", "--out", "x"], "does not exist"),
        (["run", "{tiny}", "--out", "x", "--set", "tracking.iterationz=3"], "unknown config key"),
        (["eval", "/tmp"], "not a run folder"),
        (["compare", "/tmp"], "not a run folder (no metrics.json)"),
        (["run", "{tiny}", "--out", "x", "--viewer-save", "live.txt"], "use a .rrd (rerun) or .mcap (foxglove)"),
        (["run", "{tiny}", "--out", "x", "--viewer", "rerun", "--viewer-save", "l.mcap"], "records to a .rrd file"),
    ],
)
def test_bad_input_is_one_line_and_exit_1(args, message, capsys, tiny_scene, tmp_path):
    args = [a.format(tiny=tiny_scene) if a != "x" else str(tmp_path / "out") for a in args]
    assert main(args) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err and err.startswith("sgs-slam: error:")


def test_synth_command(tmp_path):
    assert main(["synth", str(tmp_path / "s"), "--preset", "tiny", "--frames", "2", "--seed", "3"]) == 0
    assert len(list((tmp_path / "s" / "frames").glob("*.png"))) == 2
    assert np.loadtxt(tmp_path / "s" / "traj.txt").shape == (2, 16)


def test_ground_truth_file_lets_evo_reproduce_the_ate(run_dir):
    from evo.core import metrics as evo_metrics
    from evo.core import sync
    from evo.main_ape import ape
    from evo.tools import file_interface

    ref = file_interface.read_tum_trajectory_file(str(run_dir / "groundtruth.txt"))
    est = file_interface.read_tum_trajectory_file(str(run_dir / "trajectory.txt"))
    assert ref.num_poses == est.num_poses == 8
    ref, est = sync.associate_trajectories(ref, est, max_diff=1e-6)
    result = ape(ref, est, evo_metrics.PoseRelation.translation_part, align=True)
    ours = json.loads((run_dir / "metrics.json").read_text())["ate_rmse_m"]
    assert result.stats["rmse"] == pytest.approx(ours, abs=1e-6)


def test_run_yaml_records_commit_versions_and_device(run_dir):
    import torch

    from ..conftest import REPO

    info = yaml.safe_load((run_dir / "run.yaml").read_text())
    assert info["input"] and info["options"]["max_frames"] == 8  # what sgs-slam eval needs is kept
    head = subprocess.run(["git", "-C", str(REPO), "rev-parse", "HEAD"], capture_output=True, text=True, check=True)
    assert info["git"]["commit"] == head.stdout.strip() and isinstance(info["git"]["dirty"], bool)
    assert info["versions"]["torch"] == torch.__version__ and info["versions"]["sgs_slam_ros"]
    assert info["device"]["type"] == "cpu" and info["device"]["threads"] >= 1
    assert info["created_utc"].endswith("+00:00")


def test_compare_prints_one_table_across_runs(run_dir, tmp_path, capsys):
    other = tmp_path / "worse"
    other.mkdir()
    metrics = json.loads((run_dir / "metrics.json").read_text())
    metrics.update(ate_rmse_m=metrics["ate_rmse_m"] * 2, psnr_db=metrics["psnr_db"] + 1.0)
    (other / "metrics.json").write_text(json.dumps(metrics))
    assert main(["compare", str(run_dir), str(other), "--metrics", "ate_rmse_m,psnr_db,miou"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split()[:4] == ["run", "ATE", "RMSE", "cm"] and "commit" in lines[0]
    ours = next(line for line in lines if line.split()[0].endswith("tiny"))  # paths below their common parent
    theirs = next(line for line in lines if line.split()[0].endswith("worse"))
    ate_cm = 100 * json.loads((run_dir / "metrics.json").read_text())["ate_rmse_m"]
    assert f"{ate_cm:.3f}*" in ours and f"{2 * ate_cm:.3f}" in theirs  # lower ATE is best
    assert f"{metrics['psnr_db']:.2f}*" in theirs  # higher PSNR is best
    head = yaml.safe_load((run_dir / "run.yaml").read_text())["git"]["commit"][:8]
    assert head in ours and "synthetic" in ours
    assert theirs.split()[-4:] == ["-", "-", "-", "cpu"]  # no run.yaml: no provenance, device from metrics.json


def test_downscale_auto_is_chosen_from_the_inputs_width_and_recorded(tiny_scene, tmp_path, capsys):
    out = tmp_path / "auto"
    sets = [a for o in FAST_SLAM for a in ("--set", o)]
    args = ["run", str(tiny_scene), "--out", str(out), "--max-frames", "2", "--quiet", "--downscale", "auto"]
    assert main([*args, "--device", "cpu", *sets]) == 0
    assert "64x48 (downscale auto: 1)" in capsys.readouterr().err  # 64 px is under the CPU's 160: never enlarged
    assert yaml.safe_load((out / "run.yaml").read_text())["options"]["downscale"] == 1.0  # eval reopens it so


def test_auto_downscale_brings_a_cpus_width_to_160_px_and_leaves_a_gpus_alone():
    from sgs_slam_core.datasets.base import auto_downscale

    assert auto_downscale(640, cpu=True) == 4.0 and auto_downscale(1280, cpu=True) == 8.0
    assert auto_downscale(100, cpu=True) == 1.0 and auto_downscale(640, cpu=False) == 1.0
