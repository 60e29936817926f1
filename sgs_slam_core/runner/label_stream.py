"""A segmenter's label stream, reproduced from a labelled dataset (``--label-rate-hz``, ``--label-delay-ms``).

A segmenter beside a live camera labels a frame, and when it is done the newest frame then: so it
labels frames about ``1 / rate`` apart, and each label image comes out ``delay`` after its colour
image. The replay strips every frame's labels and releases those of the chosen frames that late.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sgs_slam_core.errors import ConfigError

__all__ = ["LabelStream", "label_releases"]


@dataclass(frozen=True)
class LabelStream:
    """``rate_hz``: label images a second (None: every frame's); ``delay_ms``: after their frame's release."""

    rate_hz: float | None = None
    delay_ms: float = 0.0

    def __post_init__(self) -> None:
        if self.rate_hz is not None and not self.rate_hz > 0:
            raise ConfigError(f"the label rate must be > 0 Hz, got {self.rate_hz}")
        if not self.delay_ms >= 0:
            raise ConfigError(f"the label delay must be >= 0 ms, got {self.delay_ms}")


def label_releases(times_s: np.ndarray, stream: LabelStream) -> list[tuple[float, int]]:
    """(release time s, frame index) of each label image, in release order.

    ``times_s`` [N]: the frames' release times (s, increasing). The first frame is labelled, then
    each first frame at least ``1 / rate_hz`` after the last labelled one.
    """
    chosen: list[int] = []
    period = 0.0 if stream.rate_hz is None else 1.0 / stream.rate_hz
    for i, t in enumerate(times_s):
        if not chosen or t - times_s[chosen[-1]] >= period - 1e-9:
            chosen.append(i)
    delay = stream.delay_ms / 1000.0
    return [(float(times_s[i]) + delay, i) for i in chosen]
