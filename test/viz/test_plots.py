"""The run folder's pictures: trajectory in world axes with error colouring, labelled render panels."""

import cv2
import numpy as np
import pytest
from matplotlib.collections import LineCollection

from sgs_slam_core.errors import ShapeError
from sgs_slam_core.labels import LabelTable
from sgs_slam_core.viz import RenderPanel, plot_trajectory, save_render_panels
from sgs_slam_core.viz.render_panels import render_figure
from sgs_slam_core.viz.trajectory_plot import trajectory_figure, view_axes


def upright_walk(n: int, up: str) -> np.ndarray:
    """Cameras looking horizontally, moving 2 m along x and 1 m sideways, in a z-up or y-down world."""
    poses = np.tile(np.eye(4), (n, 1, 1))
    s = np.linspace(0, 1, n)
    if up == "z":  # optical axes in a z-up world: camera x = world x, camera y (down) = -z, camera z = world y
        poses[:, :3, :3] = np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]], float)
        poses[:, :3, 3] = np.stack([2 * s, 1 * s**2, np.full(n, 1.5)], 1)
    else:  # the first camera's optical frame: y down, the walk is in x-z
        poses[:, :3, 3] = np.stack([2 * s, np.full(n, 0.1), 1 * s**2], 1)
    return poses


def test_view_axes_look_down_the_cameras_up_direction():
    z_up = view_axes(upright_walk(20, "z"))
    assert z_up.top == (0, 1) and z_up.side == (0, 2) and z_up.up_sign == 1  # x-y from above, x-z from the side
    optical = view_axes(upright_walk(20, "y"))
    assert optical.top == (0, 2) and optical.side == (0, 1) and optical.up_sign == -1  # x-z from above (-y up)


def test_trajectory_figure_colours_the_estimate_by_its_error_and_plots_it_over_time():
    gt = upright_walk(30, "z")
    est = gt.copy()
    est[:, 0, 3] += np.linspace(0, 0.05, 30)  # error grows to 5 cm
    stamps = 1_000_000_000 + np.arange(30) * 100_000_000  # 10 Hz
    fig = trajectory_figure(est, gt, stamps, title="run")
    top, side = fig.axes[:2]
    err = next(ax for ax in fig.axes if "error after alignment" in ax.get_title())
    assert (top.get_xlabel(), top.get_ylabel()) == ("x (m)", "y (m)")
    assert (side.get_xlabel(), side.get_ylabel()) == ("x (m)", "z (m)")
    lines = [c for c in top.collections if isinstance(c, LineCollection)]
    assert len(lines) == 1
    expected = 100 * np.linspace(0, 0.05, 30)
    assert np.allclose(lines[0].get_array(), 0.5 * (expected[:-1] + expected[1:]))
    legend = [t.get_text() for t in top.get_legend().get_texts()]
    assert {"ground truth", "start", "end"} <= set(legend)
    start = next(line for line in top.get_lines() if line.get_label() == "start")
    assert start.get_xydata()[0] == pytest.approx(est[0, :2, 3])
    t, e = err.get_lines()[0].get_xydata().T
    assert t == pytest.approx(np.arange(30) * 0.1) and e == pytest.approx(expected)
    assert err.get_xlabel() == "time since the first frame (s)"
    rmse = np.sqrt(np.mean(expected**2))
    assert any(f"{rmse:.2f} cm" in text.get_text() for text in err.get_legend().get_texts())
    assert any(ax.get_label() == "<colorbar>" and "error (cm)" in ax.get_ylabel() for ax in fig.axes)


def test_trajectory_without_ground_truth_flips_a_y_down_side_view(tmp_path):
    est = upright_walk(10, "y")
    fig = trajectory_figure(est, title="no gt")
    top, side = fig.axes[:2]
    assert len(fig.axes) == 2 and side.yaxis_inverted() and not top.yaxis_inverted()
    assert "up = −y" in side.get_title()
    plot_trajectory(tmp_path / "t.png", est)
    img = cv2.imread(str(tmp_path / "t.png"))
    assert img is not None and img.shape[1] > 1000
    with pytest.raises(ShapeError, match="at least 2 poses"):
        plot_trajectory(tmp_path / "x.png", est[:1])


def test_render_panels_are_labelled_with_per_frame_numbers(tmp_path):
    rng = np.random.default_rng(0)
    h, w = 24, 32
    gt_rgb = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    rgb = np.clip(gt_rgb / 255 + 0.1, 0, 1)
    gt_depth = np.full((h, w), 2.0, np.float32)
    gt_depth[:4] = 0  # no measurement
    depth = np.full((h, w), 2.05, np.float32)
    gt_labels = np.ones((h, w), np.int64)
    gt_labels[:, 16:] = 3
    labels = gt_labels.copy()
    labels[0:6, 0:8] = 3  # 48 wrong pixels
    panel = RenderPanel(gt_rgb, rgb, gt_depth, depth, gt_labels, labels)
    mse = np.mean((rgb - gt_rgb / 255) ** 2)
    assert panel.psnr_db == pytest.approx(-10 * np.log10(mse))
    assert panel.depth_l1_cm == pytest.approx(5.0, rel=1e-4)
    assert panel.accuracy == pytest.approx(1 - 48 / (h * w))
    fig = render_figure(panel, LabelTable.nyu40(), "frame 7")
    titles = [ax.get_title() for ax in fig.axes]
    assert f"rendered colour (PSNR {panel.psnr_db:.2f} dB)" in titles
    assert "rendered depth (L1 5.00 cm)" in titles and "ground truth classes" in titles
    assert any(t.startswith("rendered classes (accuracy 93.8%") for t in titles)
    bars = {ax.get_ylabel() for ax in fig.axes if ax.get_label() == "<colorbar>"}
    assert {"depth (m)", "|error| (cm)", "mean abs error (0-1)"} <= bars
    legend = [t.get_text() for t in fig.legends[0].get_texts()]
    assert legend == ["1 wall", "3 cabinet"]
    save_render_panels(tmp_path / "p.png", panel, LabelTable.nyu40(), "frame 7")
    assert cv2.imread(str(tmp_path / "p.png")).shape[0] > 3 * h
    unlabelled = render_figure(RenderPanel(gt_rgb, rgb, gt_depth, depth), LabelTable.nyu40())
    assert len([ax for ax in unlabelled.axes if ax.get_label() != "<colorbar>"]) == 6  # colour and depth rows
    with pytest.raises(ShapeError, match="both be given"):
        RenderPanel(gt_rgb, rgb, gt_depth, depth, gt_labels, None)
