"""Progress bars: elapsed, ETA and live metrics, on a terminal and in logs."""

import io
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from sgs_slam_core.config.sections import KeyframeSettings
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.metrics import ate
from sgs_slam_core.runner.progress import ProgressBar, SlamProgress
from sgs_slam_core.slam.keyframe_store import KeyframeStore


def test_log_lines_carry_elapsed_eta_rate_and_extra_and_are_rate_limited(monkeypatch):
    clock = iter([0.0, 1.0, 2.0, 10.0, 12.0, 13.0])
    monkeypatch.setattr("sgs_slam_core.runner.progress.time.perf_counter", lambda: next(clock))
    out = io.StringIO()
    bar = ProgressBar(4, "slam", stream=out, interactive=False)  # start at t = 0
    bar.update(1, "a")  # t = 1: under 5 s since start, no line
    bar.update(2, "b")  # t = 2: no line
    bar.update(3, "ATE 1.00 cm")  # t = 10: a line
    bar.update(4, "done")  # t = 12: the end always prints
    bar.update(4, "again")  # after the end: nothing
    lines = out.getvalue().splitlines()
    assert len(lines) == 2
    assert "3/4" in lines[0] and "00:10<00:03" in lines[0] and "ATE 1.00 cm" in lines[0] and "s/frame" in lines[0]
    assert "4/4" in lines[1] and "100%" in lines[1] and "00:12<00:00" in lines[1] and "done" in lines[1]


def test_terminal_bar_redraws_in_place():
    out = io.StringIO()
    bar = ProgressBar(3, "convert", stream=out, interactive=True)
    for i in range(1, 4):
        bar.update(i, f"step {i}")
    text = out.getvalue()
    assert "\r" in text and "3/3" in text and "step 3" in text and text.endswith("\n")


def fake_step(c2w):
    return SimpleNamespace(c2w=c2w, track=SimpleNamespace(lost=False))


def test_slam_progress_shows_live_ate_gaussians_and_failures():
    rng = np.random.default_rng(0)
    gts = np.tile(np.eye(4), (5, 1, 1))
    gts[:, :3, 3] = rng.normal(size=(5, 3))
    ests = gts.copy()
    ests[:, :3, 3] += rng.normal(scale=0.01, size=(5, 3))
    out = io.StringIO()
    progress = SlamProgress(5, stream=out, interactive=False)
    progress.bar.log_every_s = 0.0
    n = 12345
    gaussians = GaussianMap(
        torch.zeros(n, 3),
        torch.zeros(n, 1),
        torch.zeros(n),
        torch.zeros(n, 3),
        torch.zeros(n, 3),
        torch.zeros(n, dtype=torch.long),
        torch.zeros(n, dtype=torch.long),
    )
    slam = SimpleNamespace(gaussians=gaussians, keyframes=KeyframeStore(KeyframeSettings()), failures=0)
    for i in range(5):
        slam.failures = 1 if i == 4 else 0
        progress.log_step(SimpleNamespace(index=i, gt_c2w=gts[i]), fake_step(ests[i]), slam)
        if i == 1:
            assert progress.ate_cm is None  # fewer than three frames with ground truth
    progress.close()
    expected = 100 * ate(ests, gts).rmse
    assert progress.ate_cm == pytest.approx(expected)
    last = out.getvalue().splitlines()[-1]
    assert f"ATE {expected:.2f} cm" in last and "12,345 Gaussians (0.8 MB)" in last and "1 tracking failures" in last
    assert "0 keyframes (0 MB)" in last
    assert "5/5" in last
