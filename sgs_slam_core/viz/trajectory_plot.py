"""``trajectory.png``: camera paths in world axes (top and side views) and the error over time.

The estimate is drawn coloured by its per-frame position error against the (aligned) ground truth,
with start and end markers; the ground truth is dashed. Which world axis is "up" is read from the
cameras themselves (the mean of their image-up directions, -y of the optical frame), so the top
view looks down on a z-up TUM/Replica world as well as on a y-down camera map frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib import colormaps
from matplotlib.axes import Axes
from matplotlib.collections import LineCollection
from matplotlib.colors import Normalize
from matplotlib.figure import Figure

from sgs_slam_core.errors import ShapeError
from sgs_slam_core.viz.figures import new_figure, save_figure

__all__ = ["ViewAxes", "plot_trajectory", "trajectory_figure", "view_axes"]

_AXIS_NAMES = ("x", "y", "z")
_EST_COLOR, _GT_COLOR = "#1f6fd1", "#444444"
_CMAP = "plasma"


@dataclass(frozen=True)
class ViewAxes:
    """World axes of the two views: ``top`` (right, up on the page) looks down; ``side`` is (across, up)."""

    top: tuple[int, int]
    side: tuple[int, int]
    up_sign: float  # +1: the up axis points up; -1: it points down (optical frames, y down)

    def label(self, axis: int) -> str:
        """Axis label with units."""
        return f"{_AXIS_NAMES[axis]} (m)"


def view_axes(c2w: np.ndarray) -> ViewAxes:
    """Views for poses [N, 4, 4]: up is the world axis closest to the cameras' mean image-up (-y) direction."""
    up_dirs = -c2w[:, :3, 1]  # image "up" of each camera in world coordinates
    mean_up = up_dirs.mean(0)
    if np.linalg.norm(mean_up) < 0.3:  # cameras rolling in every direction: take the least-spread axis
        spread = np.ptp(c2w[:, :3, 3], axis=0)
        up, sign = int(np.argmin(spread)), 1.0
    else:
        up = int(np.argmax(np.abs(mean_up)))
        sign = 1.0 if mean_up[up] >= 0 else -1.0
    a, b = (up + 1) % 3, (up + 2) % 3  # a x b = +up (cyclic order)
    top = (a, b) if sign > 0 else (b, a)
    spread = np.ptp(c2w[:, :3, 3], axis=0)
    across = a if spread[a] >= spread[b] else b
    return ViewAxes(top=top, side=(across, up), up_sign=sign)


def _colored_path(ax: Axes, xy: np.ndarray, errors_cm: np.ndarray | None, norm: Normalize) -> LineCollection | None:
    if errors_cm is None or len(xy) < 2:
        ax.plot(xy[:, 0], xy[:, 1], color=_EST_COLOR, lw=1.8, label="estimate")
        return None
    segments = np.stack([xy[:-1], xy[1:]], axis=1)  # [N-1, 2, 2]
    lines = LineCollection(segments, cmap=_CMAP, norm=norm, linewidths=2.2)
    lines.set_array(0.5 * (errors_cm[:-1] + errors_cm[1:]))
    ax.add_collection(lines)
    ax.plot([], [], color=colormaps[_CMAP](0.55), lw=2.2, label="estimate (colour: error)")  # legend entry
    return lines


def _draw_view(
    ax: Axes,
    est: np.ndarray,
    gt: np.ndarray | None,
    axes: tuple[int, int],
    errors_cm: np.ndarray | None,
    norm: Normalize,
    title: str,
    flip_y: bool,
) -> LineCollection | None:
    i, j = axes
    if gt is not None:
        ax.plot(gt[:, i], gt[:, j], ls="--", color=_GT_COLOR, lw=1.2, label="ground truth")
    lines = _colored_path(ax, est[:, [i, j]], errors_cm, norm)
    ax.plot(est[0, i], est[0, j], "o", ms=8, mfc="#2ca02c", mec="black", label="start", zorder=5)
    ax.plot(est[-1, i], est[-1, j], "s", ms=8, mfc="#d62728", mec="black", label="end", zorder=5)
    ax.set_xlabel(f"{_AXIS_NAMES[i]} (m)")
    ax.set_ylabel(f"{_AXIS_NAMES[j]} (m)")
    ax.set_title(title)
    ax.grid(True, lw=0.5, alpha=0.5)
    ax.set_aspect("equal", adjustable="datalim")
    ax.autoscale_view()
    if flip_y:
        ax.invert_yaxis()
    return lines


def _time_axis(stamps_ns: np.ndarray | None, n: int) -> tuple[np.ndarray, str]:
    if stamps_ns is not None and len(stamps_ns) == n and n > 1 and np.all(np.diff(stamps_ns) > 0):
        return (stamps_ns - stamps_ns[0]) / 1e9, "time since the first frame (s)"
    return np.arange(n, dtype=float), "frame"


def plot_trajectory(
    path: str | Path,
    est_c2w: np.ndarray,  # [N, 4, 4] estimate, aligned onto the ground truth when it is given
    gt_c2w: np.ndarray | None = None,  # [N, 4, 4] ground truth of the same frames
    stamps_ns: np.ndarray | None = None,  # [N] stamps of the frames (x axis of the error plot)
    title: str = "",
) -> None:
    """Write :func:`trajectory_figure` as a PNG."""
    save_figure(trajectory_figure(est_c2w, gt_c2w, stamps_ns, title), path)


def trajectory_figure(
    est_c2w: np.ndarray,  # [N, 4, 4] estimate, aligned onto the ground truth when it is given
    gt_c2w: np.ndarray | None = None,  # [N, 4, 4] ground truth of the same frames
    stamps_ns: np.ndarray | None = None,  # [N] stamps of the frames (x axis of the error plot)
    title: str = "",
) -> Figure:
    """Top and side views in world axes; with ground truth, error colouring and the error over time."""
    est_c2w = np.asarray(est_c2w, dtype=np.float64)
    if est_c2w.ndim != 3 or est_c2w.shape[1:] != (4, 4) or len(est_c2w) < 2:
        raise ShapeError(f"need at least 2 poses [N, 4, 4], got {est_c2w.shape}")
    if gt_c2w is not None and np.shape(gt_c2w) != est_c2w.shape:
        raise ShapeError(f"ground truth {np.shape(gt_c2w)} does not match the estimate {est_c2w.shape}")
    est = est_c2w[:, :3, 3]
    gt = np.asarray(gt_c2w)[:, :3, 3] if gt_c2w is not None else None
    errors_cm = 100 * np.linalg.norm(est - gt, axis=1) if gt is not None else None
    axes = view_axes(np.asarray(gt_c2w) if gt_c2w is not None else est_c2w)
    norm = Normalize(0.0, max(float(errors_cm.max()), 1e-3) if errors_cm is not None else 1.0)

    fig = new_figure(12, 8.2 if gt is not None else 5.4)
    grid = fig.add_gridspec(2 if gt is not None else 1, 2, height_ratios=[2.4, 1] if gt is not None else [1])
    up_name = ("" if axes.up_sign > 0 else "−") + _AXIS_NAMES[axes.side[1]]
    top_ax, side_ax = fig.add_subplot(grid[0, 0]), fig.add_subplot(grid[0, 1])
    lines = _draw_view(top_ax, est, gt, axes.top, errors_cm, norm, f"top view (looking down {up_name})", False)
    _draw_view(side_ax, est, gt, axes.side, errors_cm, norm, f"side view (up = {up_name})", axes.up_sign < 0)
    top_ax.legend(loc="best", fontsize=8, framealpha=0.85)
    if lines is not None:
        fig.colorbar(lines, ax=[top_ax, side_ax], label="position error (cm)", shrink=0.85)
    if errors_cm is not None:
        err_ax = fig.add_subplot(grid[1, :])
        t, t_label = _time_axis(stamps_ns, len(errors_cm))
        rmse = float(np.sqrt(np.mean(errors_cm**2)))
        err_ax.plot(t, errors_cm, color=_EST_COLOR, lw=1.4, label="position error")
        err_ax.axhline(rmse, color="#d62728", ls="--", lw=1.0, label=f"RMSE {rmse:.2f} cm")
        err_ax.set_xlabel(t_label)
        err_ax.set_ylabel("error (cm)")
        err_ax.set_ylim(bottom=0)
        err_ax.set_xlim(t[0], t[-1])
        err_ax.set_title("camera position error after alignment (ATE per frame)")
        err_ax.grid(True, lw=0.5, alpha=0.5)
        err_ax.legend(loc="best", fontsize=8, framealpha=0.85)
    fig.suptitle(title or ("estimated trajectory" if gt is None else "estimate vs ground truth"))
    return fig
