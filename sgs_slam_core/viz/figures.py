"""Matplotlib figures without pyplot: no GUI backend, no global state, safe beside the ROS threads."""

from __future__ import annotations

from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from sgs_slam_core.fileio import atomic_write

__all__ = ["new_figure", "save_figure"]


def new_figure(width_in: float, height_in: float, dpi: int = 110) -> Figure:
    """A figure drawn by the Agg renderer (constrained layout: labels and colour bars never overlap)."""
    fig = Figure(figsize=(width_in, height_in), dpi=dpi, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig: Figure, path: str | Path) -> None:
    """Write a PNG (white background), atomically like every output (an ``OSError`` is an ``OutputError``)."""
    atomic_write(path, lambda f: fig.savefig(f, format="png", facecolor="white"))
