"""What the SLAM did with a frame: the track outcome, the map outcome, and the step that holds both."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from sgs_slam_core.frame_data import FrameTensors
from sgs_slam_core.slam.guard import TrackingState
from sgs_slam_core.slam.keyframes import Window
from sgs_slam_core.slam.map_frame import MapFrameChoice
from sgs_slam_core.slam.mapper import MapStats
from sgs_slam_core.slam.tracker import TrackResult

__all__ = ["MapOutcome", "StepResult", "TrackOutcome"]


@dataclass(frozen=True)
class TrackOutcome:
    """The pose of one frame (tracked, ground truth, or registered from elsewhere)."""

    index: int  # frame counter of this Slam (0 = first processed frame)
    stamp_ns: int
    c2w: np.ndarray  # [4, 4] camera-to-world (map frame)
    result: TrackResult | None  # None when not tracked (first frame, ground truth, registered)
    failure_reason: str | None  # why the guard rejected the pose (the frame is then not mapped)
    time_s: float
    frame_data: FrameTensors | None = field(default=None, repr=False, compare=False)  # uploaded once, mapped too
    map_frame: MapFrameChoice | None = None  # how the map frame was chosen (the run's first frame)
    state: TrackingState = "ok"  # lost: the camera is lost, the pose is the last accepted one

    @property
    def lost(self) -> bool:
        """True when the camera was lost at this frame (its pose is not an estimate)."""
        return self.state == "lost"

    @property
    def failed(self) -> bool:
        """True when the failure guard rejected the frame."""
        return self.failure_reason is not None

    def without_tensors(self) -> TrackOutcome:
        """This outcome without the frame's tensors and the tracker's rendering, to keep once mapped."""
        result = None if self.result is None else replace(self.result, rendering=None)
        return replace(self, frame_data=None, result=result)


@dataclass(frozen=True)
class MapOutcome:
    """What mapping did with one frame."""

    stats: MapStats | None  # None when the map was not optimised (failure, or not a mapping frame)
    window: Window | None
    keyframe: bool  # the frame was kept as a keyframe
    added: int  # Gaussians added by initialisation / densification
    time_s: float  # densification + mapping
    timings: dict[str, float] = field(default_factory=dict)  # s per stage

    @staticmethod
    def not_mapped() -> MapOutcome:
        """A frame mapping left alone (rejected by the guard, or not mapped yet)."""
        return MapOutcome(None, None, False, 0, 0.0)


@dataclass(frozen=True)
class StepResult:
    """What happened to one frame: its track and map outcomes, and the map's size after them."""

    track: TrackOutcome
    map: MapOutcome
    num_gaussians: int

    @property
    def index(self) -> int:
        """Frame counter of the Slam (0 = first processed frame)."""
        return self.track.index

    @property
    def stamp_ns(self) -> int:
        """The frame's time stamp (ns)."""
        return self.track.stamp_ns

    @property
    def c2w(self) -> np.ndarray:  # [4, 4]
        """The estimated camera-to-world pose (map frame)."""
        return self.track.c2w

    @property
    def timings(self) -> dict[str, float]:
        """Seconds per stage: tracking, then mapping's."""
        return {"track": self.track.time_s, **self.map.timings}
