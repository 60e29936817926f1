"""groundtruth.txt and run.yaml provenance."""

import subprocess

import numpy as np
import torch
import yaml

from sgs_slam_core.metrics import read_tum_trajectory
from sgs_slam_core.runner import run_record
from sgs_slam_core.runner.run_info import write_run_info


def test_ground_truth_keeps_only_frames_that_have_it(tmp_path):
    poses = [np.eye(4) for _ in range(4)]
    for i, p in enumerate(poses):
        p[:3, 3] = [i, 2 * i, 0.5]
    gts = [poses[0], None, poses[2], poses[3]]
    stamps = [1_000_000_000 + 33_000_000 * i for i in range(4)]
    assert run_record.write_ground_truth(tmp_path / "gt.txt", stamps, gts) == 3
    read_stamps, read_poses = read_tum_trajectory(tmp_path / "gt.txt")
    assert read_stamps.tolist() == [stamps[0], stamps[2], stamps[3]]
    assert np.allclose(read_poses[:, :3, 3], [[0, 0, 0.5], [2, 4, 0.5], [3, 6, 0.5]])
    assert run_record.write_ground_truth(tmp_path / "none.txt", stamps, [None] * 4) == 0
    assert not (tmp_path / "none.txt").exists()


def test_an_installed_copy_inside_another_repository_reports_no_commit(tmp_path, monkeypatch):
    subprocess.run(["git", "init", "-q", str(tmp_path)], check=True)
    copy = tmp_path / "venv" / "lib" / "site-packages"
    copy.mkdir(parents=True)
    monkeypatch.setattr(run_record, "_SOURCE_DIR", copy.resolve())
    assert run_record.git_info() is None
    monkeypatch.setattr(run_record, "_SOURCE_DIR", tmp_path.resolve())  # the checkout itself (no commit yet)
    assert run_record.git_info() is None


def test_run_yaml_puts_provenance_after_the_input_description(tmp_path):
    record = {"input": "/data/x", "preset": "tum", **run_record.environment(torch.device("cpu"))}
    write_run_info(tmp_path / "run.yaml", record, "complete")
    loaded = yaml.safe_load((tmp_path / "run.yaml").read_text())
    assert loaded == {**record, "status": "complete"} and list(loaded)[:2] == ["input", "preset"]
    assert loaded["versions"]["torch"] == torch.__version__ and loaded["device"]["type"] == "cpu"
    assert loaded["device"]["threads"] == torch.get_num_threads() and loaded["device"]["name"]
