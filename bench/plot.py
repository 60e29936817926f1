"""Line charts for benchmark results, drawn with OpenCV (no plotting library in the dependencies)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

__all__ = ["Series", "line_panel", "save_panels"]

_FONT = cv2.FONT_HERSHEY_SIMPLEX


@dataclass(frozen=True)
class Series:
    """One line: y values over frame index, a legend name and a BGR colour."""

    name: str
    values: np.ndarray  # [T]
    color: tuple[int, int, int]


def _nice_max(value: float) -> float:
    if value <= 0:
        return 1.0
    exp = 10 ** np.floor(np.log10(value))
    for step in (1, 2, 2.5, 5, 10):
        if step * exp >= value:
            return float(step * exp)
    return float(10 * exp)


def line_panel(
    series: list[Series],
    title: str,
    y_label: str,
    size: tuple[int, int] = (720, 300),
    x_label: str = "frame",
    x_step: float = 1,
) -> np.ndarray:
    """A white panel [H, W, 3] with axes, 5 y ticks, the lines and a legend (value i is at x = i * x_step)."""
    width, height = size
    left, right, top, bottom = 70, 15, 30, 35
    img = np.full((height, width, 3), 255, np.uint8)
    frames = max(len(s.values) for s in series)
    y_max = _nice_max(max(float(np.nanmax(s.values)) for s in series if len(s.values)))
    plot_w, plot_h = width - left - right, height - top - bottom

    def xy(i: float, v: float) -> tuple[int, int]:
        return int(left + plot_w * i / max(frames - 1, 1)), int(top + plot_h * (1 - v / y_max))

    for k in range(6):
        y = top + plot_h * k // 5
        cv2.line(img, (left, y), (width - right, y), (225, 225, 225), 1)
        cv2.putText(img, f"{y_max * (1 - k / 5):g}", (4, y + 4), _FONT, 0.38, (60, 60, 60), 1, cv2.LINE_AA)
    cv2.rectangle(img, (left, top), (width - right, height - bottom), (0, 0, 0), 1)
    for k in range(5):
        frame = round((frames - 1) * k / 4)
        x, _ = xy(frame, 0)
        text = f"{frame * x_step:g}"
        cv2.putText(img, text, (x - 4 * len(text), height - bottom + 15), _FONT, 0.38, (60, 60, 60), 1, cv2.LINE_AA)
    cv2.putText(img, x_label, (width // 2 - 4 * len(x_label), height - 6), _FONT, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, f"{title} ({y_label})", (left, 20), _FONT, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    for n, s in enumerate(series):
        points = np.array([xy(i, v) for i, v in enumerate(s.values) if np.isfinite(v)], np.int32)
        if len(points) > 1:
            cv2.polylines(img, [points], False, s.color, 1, cv2.LINE_AA)
        x = width - right - 150
        cv2.line(img, (x, top + 14 + 16 * n), (x + 20, top + 14 + 16 * n), s.color, 2)
        cv2.putText(img, s.name, (x + 26, top + 18 + 16 * n), _FONT, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    return img


def save_panels(path: str | Path, panels: list[np.ndarray]) -> None:
    """Stack panels vertically into one PNG."""
    cv2.imwrite(str(path), np.concatenate(panels, 0))
