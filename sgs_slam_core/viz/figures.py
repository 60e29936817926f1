"""Matplotlib figures without pyplot: no GUI backend, no global state, safe beside the ROS threads."""

from __future__ import annotations

from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

__all__ = ["new_figure", "save_figure"]


def new_figure(width_in: float, height_in: float, dpi: int = 110) -> Figure:
    """A figure drawn by the Agg renderer (constrained layout: labels and colour bars never overlap)."""
    fig = Figure(figsize=(width_in, height_in), dpi=dpi, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig: Figure, path: str | Path) -> None:
    """Write a PNG (white background)."""
    fig.savefig(str(path), facecolor="white")
