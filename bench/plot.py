"""Line charts for benchmark results, drawn with matplotlib (Agg, no pyplot state).

:func:`line_chart` builds a labelled figure (title, axis labels with units, ticks, grid, legend);
:func:`line_panel` rasterises one to an image so that several can be stacked by :func:`save_panels`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from matplotlib.figure import Figure

from sgs_slam_core.viz.figures import new_figure

__all__ = ["Series", "line_chart", "line_panel", "save_panels"]

_DPI = 100


@dataclass(frozen=True)
class Series:
    """One line: y values over frame index, a legend name and a BGR colour (0-255)."""

    name: str
    values: np.ndarray  # [T]
    color: tuple[int, int, int]

    @property
    def rgb(self) -> tuple[float, float, float]:
        """The colour as matplotlib's RGB in [0, 1]."""
        b, g, r = self.color
        return (r / 255, g / 255, b / 255)


def line_chart(
    series: list[Series],
    title: str,
    y_label: str,
    size: tuple[int, int] = (720, 300),
    x_label: str = "frame",
    x_step: float = 1,
) -> Figure:
    """A figure of ``size`` (W, H) pixels: one line per series (value i at x = i * x_step), y from 0."""
    fig = new_figure(size[0] / _DPI, size[1] / _DPI, dpi=_DPI)
    ax = fig.add_subplot()
    for s in series:
        values = np.asarray(s.values, dtype=float)
        ax.plot(np.arange(len(values)) * x_step, values, color=s.rgb, lw=1.4, label=s.name)
    ax.set_title(title, fontsize=10)
    ax.set_xlabel(x_label)
    ax.set_ylabel(y_label)
    ax.set_ylim(bottom=0)
    frames = max((len(s.values) for s in series), default=1)
    ax.set_xlim(0, max(frames - 1, 1) * x_step)
    ax.grid(True, lw=0.5, alpha=0.5)
    ax.legend(loc="best", fontsize=8, framealpha=0.85)
    return fig


def line_panel(
    series: list[Series],
    title: str,
    y_label: str,
    size: tuple[int, int] = (720, 300),
    x_label: str = "frame",
    x_step: float = 1,
) -> np.ndarray:
    """:func:`line_chart` as a BGR image [H, W, 3] uint8 (for :func:`save_panels` or cv2); value i at x = i * x_step."""
    fig = line_chart(series, title, y_label, size, x_label, x_step)
    fig.canvas.draw()
    rgba = np.asarray(fig.canvas.buffer_rgba())  # type: ignore[attr-defined]
    return np.ascontiguousarray(rgba[..., 2::-1])


def save_panels(path: str | Path, panels: list[np.ndarray]) -> None:
    """Stack panels vertically into one PNG."""
    cv2.imwrite(str(path), np.concatenate(panels, 0))
