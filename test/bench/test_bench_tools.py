"""The benchmark helpers measure what they claim: profiler labels, timing plots, bag throughput set-up."""

from __future__ import annotations

import cv2
import numpy as np

from bench.bench_slam import LABELS, profile_frames, profile_table
from bench.plot import Series, line_panel, save_panels
from sgs_slam_core.config import load_config
from sgs_slam_core.datasets import open_dataset

from ..conftest import FAST_SLAM


def test_profile_breaks_frames_down_by_the_pipeline_labels(tiny_scene):
    config = load_config("synthetic", overrides=[*FAST_SLAM, "device=cpu"])
    rows, wall_ms = profile_frames(open_dataset(tiny_scene), config, warmup=2, count=2)
    found = {r.label: r for r in rows}
    for label in ("track.render", "track.backward", "map.render", "map.backward", "densify", "upload"):
        assert label in found and found[label].host_ms > 0, label
    assert set(found) <= set(LABELS)
    assert found["track.render"].calls >= 1 and found["map.render"].calls == 15  # one render per mapping iteration
    assert sum(r.host_ms for r in rows) < wall_ms  # labels do not nest, so they cannot exceed the frame time
    table = profile_table(rows, wall_ms, "cpu")
    assert "| track.render |" in table and "unlabelled" in table


def test_line_panel_draws_each_series_in_its_colour(tmp_path):
    up = Series("up", np.arange(50, dtype=float), (255, 0, 0))
    flat = Series("flat", np.full(50, 10.0), (0, 0, 255))
    panel = line_panel([up, flat], "t", "ms", size=(400, 200))
    assert panel.shape == (200, 400, 3)
    blue = (panel[..., 0] > 200) & (panel[..., 1] < 80) & (panel[..., 2] < 80)
    red = (panel[..., 2] > 200) & (panel[..., 0] < 80) & (panel[..., 1] < 80)
    assert blue.sum() > 100 and red.sum() > 100
    rows = np.nonzero(red[:, 80:220].any(1))[0]  # left of the legend
    assert rows.max() - rows.min() <= 2 and abs(rows.mean() - (30 + 135 * 0.8)) < 2  # y = 10 of 0..50
    save_panels(tmp_path / "p.png", [panel, panel])
    assert cv2.imread(str(tmp_path / "p.png")).shape == (400, 400, 3)
