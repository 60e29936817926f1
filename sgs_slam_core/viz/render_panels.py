"""``renders/frame_NNNNNN.png``: ground truth / rendered / error for colour, depth and semantics.

Each row is labelled and carries its per-frame number (PSNR, depth L1, pixel accuracy); depth shares
one colour bar in metres between ground truth and rendering, errors have their own colour bars.
Pixels without ground-truth depth are drawn in black and left out of the depth error.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from matplotlib import colormaps
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.image import AxesImage
from matplotlib.patches import Patch

from sgs_slam_core.errors import ShapeError
from sgs_slam_core.labels import LabelTable
from sgs_slam_core.viz.figures import new_figure, save_figure

__all__ = ["RenderPanel", "render_figure", "save_render_panels"]

_MAX_LEGEND = 14


class RenderPanel:
    """One evaluated frame: ground truth and rendering as numpy arrays."""

    def __init__(
        self,
        gt_rgb: np.ndarray,  # [H, W, 3] uint8
        rgb: np.ndarray,  # [H, W, 3] float in [0, 1] (rendered)
        gt_depth: np.ndarray,  # [H, W] m, 0 = no measurement
        depth: np.ndarray,  # [H, W] m (rendered)
        gt_labels: np.ndarray | None = None,  # [H, W] class ids
        labels: np.ndarray | None = None,  # [H, W] decoded class ids
    ) -> None:
        h, w = gt_depth.shape
        for name, arr, shape in (("gt_rgb", gt_rgb, (h, w, 3)), ("rgb", rgb, (h, w, 3)), ("depth", depth, (h, w))):
            if arr.shape != shape:
                raise ShapeError(f"{name} must be {list(shape)}, got {list(arr.shape)}")
        if (gt_labels is None) != (labels is None) or (gt_labels is not None and gt_labels.shape != (h, w)):
            raise ShapeError("ground-truth and rendered labels must both be given, [H, W] like the depth")
        self.gt_rgb = gt_rgb.astype(np.float64) / 255
        self.rgb = np.clip(rgb.astype(np.float64), 0, 1)
        self.gt_depth = gt_depth.astype(np.float64)
        self.depth = np.nan_to_num(depth.astype(np.float64), nan=0.0, posinf=0.0)
        self.gt_labels, self.labels = gt_labels, labels

    @property
    def psnr_db(self) -> float:
        """PSNR over all pixels (dB, data range 1)."""
        mse = float(np.mean((self.rgb - self.gt_rgb) ** 2))
        return float("inf") if mse == 0 else -10 * np.log10(mse)

    @property
    def depth_l1_cm(self) -> float:
        """Mean |rendered - ground truth| over pixels with ground-truth depth (cm)."""
        valid = self.gt_depth > 0
        return float(100 * np.abs(self.depth - self.gt_depth)[valid].mean()) if valid.any() else float("nan")

    @property
    def accuracy(self) -> float | None:
        """Fraction of labelled pixels whose class is right."""
        if self.gt_labels is None or self.labels is None:
            return None
        labelled = self.gt_labels > 0
        return float((self.labels == self.gt_labels)[labelled].mean()) if labelled.any() else None


def _image(ax: Axes, image: np.ndarray, title: str, **kwargs: Any) -> AxesImage:
    handle = ax.imshow(image, interpolation="nearest", **kwargs)
    ax.set_title(title, fontsize=9)
    ax.set_xticks([])
    ax.set_yticks([])
    return handle


def _colour_row(fig: Figure, axes: list[Axes], p: RenderPanel) -> None:
    _image(axes[0], p.gt_rgb, "ground truth colour")
    _image(axes[1], p.rgb, f"rendered colour (PSNR {p.psnr_db:.2f} dB)")
    err = np.abs(p.rgb - p.gt_rgb).mean(axis=2)
    h = _image(axes[2], err, "colour error |rendered - truth|", cmap="magma", vmin=0, vmax=max(float(err.max()), 1e-3))
    fig.colorbar(h, ax=axes[2], label="mean abs error (0-1)", shrink=0.9)


def _depth_row(fig: Figure, axes: list[Axes], p: RenderPanel) -> None:
    valid = p.gt_depth > 0
    vmax = float(p.gt_depth[valid].max()) if valid.any() else max(float(p.depth.max()), 1e-3)
    cmap = colormaps["turbo"].with_extremes(bad="black")
    _image(
        axes[0],
        np.ma.masked_where(~valid, p.gt_depth),
        "ground truth depth (black: none)",
        cmap=cmap,
        vmin=0,
        vmax=vmax,
    )
    h = _image(
        axes[1],
        np.ma.masked_where(p.depth <= 0, p.depth),
        f"rendered depth (L1 {p.depth_l1_cm:.2f} cm)",
        cmap=cmap,
        vmin=0,
        vmax=vmax,
    )
    fig.colorbar(h, ax=axes[:2], label="depth (m)", shrink=0.9)
    err_cm = np.ma.masked_where(~valid, 100 * np.abs(p.depth - p.gt_depth))
    top = float(np.percentile(err_cm.compressed(), 99)) if err_cm.count() else 1.0
    e = _image(
        axes[2],
        err_cm,
        "depth error (grey: no ground truth; scale to 99th pct.)",
        cmap=colormaps["magma"].with_extremes(bad="#b0b0b0"),
        vmin=0,
        vmax=max(top, 1e-3),
    )
    fig.colorbar(e, ax=axes[2], label="|error| (cm)", shrink=0.9)


def _semantic_row(fig: Figure, axes: list[Axes], p: RenderPanel, table: LabelTable) -> None:
    assert p.gt_labels is not None and p.labels is not None
    _image(axes[0], table.colorize(p.gt_labels), "ground truth classes")
    acc = p.accuracy
    _image(axes[1], table.colorize(p.labels), "rendered classes" + (f" (accuracy {100 * acc:.1f}%)" if acc else ""))
    labelled = p.gt_labels > 0
    wrong = labelled & (p.labels != p.gt_labels)
    shown = 0.35 * table.colorize(p.gt_labels).astype(np.float64) / 255 + 0.4 * labelled[..., None]
    shown[wrong] = (0.85, 0.1, 0.1)
    _image(axes[2], shown, "wrong class in red (black: unlabelled)")
    ids = [int(i) for i in np.unique(np.concatenate([p.gt_labels.ravel(), p.labels.ravel()])) if i > 0]
    handles = [Patch(color=np.array(table.color_of(i)) / 255, label=f"{i} {table.name_of(i)}") for i in ids]
    if len(handles) > _MAX_LEGEND:
        handles = [*handles[: _MAX_LEGEND - 1], Patch(color="white", label=f"... {len(ids) - _MAX_LEGEND + 1} more")]
    fig.legend(
        handles=handles,
        loc="outside lower center",
        ncols=min(len(handles), 7),
        fontsize=8,
        title="classes",
        title_fontsize=8,
        frameon=False,
    )


def save_render_panels(path: str | Path, panel: RenderPanel, table: LabelTable, title: str = "") -> None:
    """Write :func:`render_figure` as a PNG."""
    save_figure(render_figure(panel, table, title), path)


def render_figure(panel: RenderPanel, table: LabelTable, title: str = "") -> Figure:
    """The 2- or 3-row comparison: colour, depth, and semantics when the frame is labelled."""
    rows = 3 if panel.gt_labels is not None else 2
    h, w = panel.gt_depth.shape
    cell = 3.6  # inches per panel width
    fig = new_figure(3 * cell + 1.6, rows * cell * h / w + 0.9 * rows + (0.9 if rows == 3 else 0.3))
    axes = fig.subplots(rows, 3)
    _colour_row(fig, list(axes[0]), panel)
    _depth_row(fig, list(axes[1]), panel)
    if rows == 3:
        _semantic_row(fig, list(axes[2]), panel, table)
    fig.suptitle(title)
    return fig
