"""The benchmark helpers measure what they claim: profiler labels, timing plots, bag throughput set-up."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from bench.bench_prune import prune_by_mask, stepped_optimizer
from bench.bench_slam import LABELS, ops_table, profile_frames, profile_table
from bench.plot import Series, line_chart, line_panel, save_panels
from sgs_slam_core.config import load_config
from sgs_slam_core.datasets import open_dataset

from ..conftest import FAST_SLAM

pytestmark = pytest.mark.slow  # end to end: left out of make test-fast


def test_profile_breaks_frames_down_by_the_pipeline_labels(tiny_scene):
    config = load_config("synthetic", overrides=[*FAST_SLAM, "device=cpu", "tracking.method=adam"])  # its labels
    prof = profile_frames(open_dataset(tiny_scene), config, warmup=2, count=2)
    rows, wall_ms = prof.rows, prof.wall_ms
    found = {r.label: r for r in rows}
    for label in ("track.render", "track.backward", "map.render", "map.backward", "densify", "upload"):
        assert label in found and found[label].host_ms > 0, label
    assert set(found) <= set(LABELS)
    assert found["track.render"].calls >= 1 and found["map.render"].calls == 15  # one render per mapping iteration
    assert sum(r.host_ms for r in rows) < wall_ms  # labels do not nest, so they cannot exceed the frame time
    table = profile_table(rows, wall_ms, "cpu")
    assert "| track.render |" in table and "unlabelled" in table
    assert prof.top_ops and all(op.label not in LABELS for op in prof.top_ops)
    assert prof.top_ops[0].host_ms >= prof.top_ops[-1].host_ms > 0  # the busiest first
    assert prof.syncs["aten::_local_scalar_dense"] > 0  # the CPU path reads values back too (.item())
    ops = ops_table(prof)
    assert f"| `{prof.top_ops[0].label}` |" in ops and "Host waits on the device per frame" in ops


def test_line_chart_is_labelled_and_draws_each_series(tmp_path):
    up = Series("up", np.arange(50, dtype=float), (255, 0, 0))  # BGR blue
    flat = Series("flat", np.full(50, 10.0), (0, 0, 255))  # BGR red
    fig = line_chart([up, flat], "time per frame", "ms")
    ax = fig.axes[0]
    assert (ax.get_title(), ax.get_xlabel(), ax.get_ylabel()) == ("time per frame", "frame", "ms")
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["up", "flat"]
    lines = ax.get_lines()
    assert lines[0].get_color() == (0.0, 0.0, 1.0) and lines[1].get_color() == (1.0, 0.0, 0.0)
    assert np.array_equal(lines[1].get_ydata(), np.full(50, 10.0)) and ax.get_ylim()[0] == 0
    assert len(ax.get_yticks()) >= 3  # real ticks with values
    panel = line_panel([up, flat], "t", "ms", size=(400, 200))
    assert panel.shape == (200, 400, 3) and panel.dtype == np.uint8
    blue = (panel[..., 0] > 200) & (panel[..., 1] < 80) & (panel[..., 2] < 80)
    red = (panel[..., 2] > 200) & (panel[..., 0] < 80) & (panel[..., 1] < 80)
    assert blue.sum() > 100 and red.sum() > 100  # BGR image: each line in its colour
    save_panels(tmp_path / "p.png", [panel, panel])
    assert cv2.imread(str(tmp_path / "p.png")).shape == (400, 400, 3)


def test_accuracy_summary_pairs_variants_by_seed():
    from bench.bench_accuracy import METRICS, Variant, summary

    assert Variant.parse("base") == Variant("base", ())
    assert Variant.parse("w:densify.front_window=1,seed=3") == Variant("w", ("densify.front_window=1", "seed=3"))
    keys = [key for key, _, _ in METRICS]
    values = {
        "a": {key: [1.0, 2.0, 3.0] for key in keys},
        "b": {key: [1.5, 2.5, 3.5] for key in keys} | {"miou": [float("nan")] * 3},
    }
    table = summary(values, ["a", "b"])
    assert "| a | 2 ± 1 |" in table
    assert "2.5 ± 1 (Δ +0.5 ± 0)" in table  # the same shift at every seed: no spread in the difference
    assert table.splitlines()[-1].count("| - |") == 1  # mIoU: nothing measured


def test_long_run_loops_report_their_means_and_the_drift_from_loop_two(tmp_path):
    from bench.bench_longrun import RESULTS, Sample, drift, order, per_loop, report

    assert order(4, 8) == [0, 1, 2, 3, 2, 1, 0, 1]  # there and back: a loop is 2 * (4 - 1) frames
    period = 6
    samples = []
    for f in range(2, 3 * period + 1, 2):
        later = f > period  # loops 2 and 3 hold more than loop 1, and the same as each other
        rss, gaussians = 400.0 + 10 * later, 1000 + 50 * later
        work = 2000 + 100 * later
        samples.append(Sample(f, rss, 410.0, gaussians, 1.0, 4, 0.5, 0, 1.0, 0.9, 800.0 + f, 0.2, 0.8, 2.0, work, 9.0))
    est = np.stack([np.eye(4)] * 3 * period)
    gt = est.copy()
    rows = per_loop(samples, est, gt, period)
    assert [r.loop for r in rows] == [1, 2, 3] and rows[0].frames == "1-6"
    assert rows[0].gaussians == 1000 and rows[1].gaussians == rows[2].gaussians == 1050
    assert rows[2].gpu_peak_mb == 800.0 + 3 * period  # the highest of the loop's samples
    assert drift(rows, "gaussians") == 0.0 and drift(rows, "rss_mb") == 0.0
    assert rows[0].intersections == 2000 and rows[2].intersections == 2100 and rows[1].map_s == pytest.approx(0.8)
    body = report(rows, samples, RESULTS / "x.png", "What ran.")
    assert "| GPU peak MB |" in body and "| 818 |" in body and "Gaussians 0.0 %" in body
    assert "| tile pairs M |" in body and "tile pairs 0.0 %" in body


def test_the_prune_bench_times_two_ways_to_the_same_rows():
    keep = torch.arange(50) % 4 != 0
    before, now = stepped_optimizer(50, 3), stepped_optimizer(50, 3)
    prune_by_mask(before, keep)
    assert now.prune(keep) == 13
    for name in now.names:
        assert torch.equal(before.params[name], now.params[name]) and before.params[name].requires_grad
        assert torch.equal(before.adam.state[name].exp_avg_sq, now.adam.state[name].exp_avg_sq)
    assert torch.equal(before.result().labels, now.result().labels)


def test_a_replay_reads_the_nodes_final_counts_integers_only():
    from bench.bench_replay_loss import final_counts

    log = (
        "[INFO] [1732870000.5] [tracking_node]: final counts: frames_in 573, frames_dropped 40, "
        "dropped[queue] 3, frames_tracked 533, mapping_steps_per_frame 2.0, labels_in 60, labels_fused 57"
    )
    counts = final_counts(log, "done: 573 frames")
    assert counts == {
        "frames_in": 573,
        "frames_dropped": 40,
        "frames_tracked": 533,
        "labels_in": 60,
        "labels_fused": 57,
        "sent": 573,
        "mapping_steps_per_frame": 2.0,
    }


def test_a_live_ab_row_and_medians_read_a_runs_metrics():
    from bench.bench_live_ab import HEADERS, medians, row

    keys = ("frames_in", "frames_tracked", "ate_rmse_m", "track_ms_per_frame", "map_steps_per_frame")
    values = [(100, 90, 0.03, 21.0, 0.5), (100, 80, 0.05, 30.0, 0.4), (100, 96, None, 20.0, 1.0)]
    runs = [dict(zip(keys, v, strict=True)) for v in values]
    first = row(1, "new", "abc1234", {**runs[0], "tracking_lost_events": 2})
    assert len(first) == len(HEADERS) and first[3] == "90 of 100 (90%)" and first[4] == "3.00" and first[-1] == 2
    assert row(3, "base", "abc1234", runs[2])[4] == "-"
    assert medians(runs) == "90% tracked at 4.00 cm"  # ATE median over the runs that have one


def test_the_view_density_counts_a_layer_behind_an_opaque_wall_as_hidden():
    from bench.bench_view_density import born_by, density
    from sgs_slam_core.gaussians import GaussianMap
    from sgs_slam_core.geometry.camera import Intrinsics
    from sgs_slam_core.kernels.factory import build_kernels
    from sgs_slam_core.render.settings import RenderSettings

    k = Intrinsics(40.0, 40.0, 19.5, 14.5, 40, 30)
    u, v = torch.meshgrid(torch.arange(40.0), torch.arange(30.0), indexing="xy")
    rays = torch.stack([(u.reshape(-1) - k.cx) / k.fx, (v.reshape(-1) - k.cy) / k.fy, torch.ones(1200)], dim=1)
    means = torch.cat([rays * 1.0, rays * 1.5])  # a wall of one Gaussian a pixel at 1 m, and a copy at 1.5 m
    n = len(means)
    g = GaussianMap(
        means=means,
        log_scales=torch.full((n, 1), float(np.log(0.02))),  # 2 cm: a pixel's footprint at 1 m is 2.5 cm
        logit_opacities=torch.full((n,), 6.0),  # opaque
        colors=torch.full((n, 3), 0.5),
        semantics=torch.zeros(n, 0),
        labels=torch.zeros(n, dtype=torch.long),
        birth_frame=torch.cat([torch.zeros(1200, dtype=torch.long), torch.full((1200,), 5)]),
    )
    assert len(born_by(g, 4).means) == 1200 and len(born_by(g, 5).means) == n
    at_frame_4 = density(build_kernels(RenderSettings(), g.device), g, k, np.eye(4), 4)
    assert at_frame_4.then == 1200 and at_frame_4.now == n
    assert at_frame_4.hidden == pytest.approx(0.5, abs=0.02)  # the copy behind, every one of it
    assert at_frame_4.then_ms > 0 and at_frame_4.now_ms > 0
