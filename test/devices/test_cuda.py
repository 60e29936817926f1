"""The GPU path end to end (skipped without CUDA; run by ``bench/gpu_suite.sh`` on a lent GPU)."""

import dataclasses
import json

import numpy as np
import pytest
import torch

from sgs_slam_core.config import load_config
from sgs_slam_core.datasets import open_dataset
from sgs_slam_core.metrics import ate
from sgs_slam_core.runner import run_offline
from sgs_slam_core.runner.realtime import RealtimeOptions

from ..conftest import FAST_SLAM

pytestmark = [pytest.mark.gpu, pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")]


def test_offline_run_on_cuda_finishes_and_evaluates(tiny_scene, tmp_path):
    dataset = open_dataset(tiny_scene)
    config = load_config("synthetic", overrides=[*FAST_SLAM, "device=cuda"])
    result = run_offline(dataset, config, tmp_path / "run", show_progress=False)
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["device"].startswith("cuda") and metrics["frames"] == len(dataset)
    assert metrics["ate_rmse_m"] < 0.03 and metrics["psnr_db"] > 25 and metrics["miou"] > 0.5
    assert metrics["peak_memory_mb"] > 0 and result.slam.gaussians.means.is_cuda


def test_realtime_run_on_cuda_maps_on_its_own_stream(tiny_scene, tmp_path):
    dataset = open_dataset(tiny_scene)
    config = load_config("synthetic", overrides=[*FAST_SLAM, "device=cuda"])
    run_offline(dataset, config, tmp_path / "rt", show_progress=False, realtime=RealtimeOptions(10.0))
    metrics = json.loads((tmp_path / "rt" / "metrics.json").read_text())
    assert metrics["frames_in"] == len(dataset) == metrics["frames_tracked"] + metrics["frames_dropped"]
    assert metrics["frames_mapped"] >= 1 and metrics["ate_rmse_m"] < 0.05


def test_slam_node_on_cuda(tiny_scene, tmp_path):
    pytest.importorskip("rclpy", reason="the ROS 2 wheels are not installed")
    from sgs_slam_ros.slam_node import build_slam_nodes

    from ..polling import wait_for
    from ..ros.helpers import Feeder, Spinner, new_context, node_params, shut_down

    ds = open_dataset(tiny_scene)
    frames = [
        dataclasses.replace(ds[i], depth=(np.round(ds[i].depth * 1000) / 1000).astype(np.float32)) for i in range(6)
    ]
    ctx = new_context()
    nodes = build_slam_nodes(context=ctx, parameter_overrides=node_params(device="cuda"))
    feeder = Feeder(ctx)
    spinner = Spinner(ctx, [*nodes, feeder])
    try:
        assert wait_for(feeder.connected, 10.0)
        for f in frames:
            feeder.publish(f)
            assert wait_for(lambda f=f: f.stamp_ns in feeder.poses, 60.0), f"no pose for frame {f.index}"
        from msg_adapters import pose_to_c2w

        est = np.stack([pose_to_c2w(feeder.poses[f.stamp_ns]) for f in frames])
        assert ate(est, np.stack([f.gt_c2w for f in frames])).rmse < 0.03
        assert nodes[1].pipeline.wait_idle(30.0) and nodes[1].pipeline.stats.errors == 0
        assert nodes[1].pipeline.slam.gaussians.means.is_cuda
    finally:
        shut_down(ctx, [*nodes, feeder], spinner)
