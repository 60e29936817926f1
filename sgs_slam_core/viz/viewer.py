"""Live views of a run without ROS: ``sgs-slam run ... --viewer rerun|foxglove``.

A viewer receives ``log_step(frame, step, slam)`` after every processed frame and ``close()`` at the
end. Two backends, both optional extras (``pip install 'sgs_slam_ros[viewer]'``):

* ``rerun`` (rerun-sdk): spawns the Rerun viewer when a display and the ``rerun`` executable are
  there, otherwise serves the stream and a web viewer on localhost and prints the address.
* ``foxglove`` (foxglove-sdk): a Foxglove WebSocket server (``ws://127.0.0.1:8765``) to open in
  the Foxglove app.

Either one can also record the stream to a file (``.rrd`` / ``.mcap``) instead of or beside the
live view. A backend that fails while the run goes on is logged once and switched off: a viewer
never stops the mapping.
"""

from __future__ import annotations

import abc
import importlib.util
import logging
import socket
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Literal, Protocol

from sgs_slam_core.errors import BackendUnavailableError, ConfigError
from sgs_slam_core.viz.snapshot import MapPoints, Snapshot, SnapshotRecorder, ViewerSettings

if TYPE_CHECKING:
    from sgs_slam_core.frame import Frame
    from sgs_slam_core.labels import LabelTable
    from sgs_slam_core.slam.system import Slam, StepResult

__all__ = [
    "VIEWER_KINDS",
    "StreamingViewer",
    "Viewer",
    "ViewerKind",
    "ViewerOptions",
    "check_port_free",
    "kind_of_file",
    "open_viewer",
]

log = logging.getLogger(__name__)

ViewerKind = Literal["rerun", "foxglove"]
VIEWER_KINDS: tuple[ViewerKind, ...] = ("rerun", "foxglove")
_EXTENSIONS: dict[str, ViewerKind] = {".rrd": "rerun", ".mcap": "foxglove"}
_PACKAGES = {"rerun": ("rerun", "rerun-sdk"), "foxglove": ("foxglove", "foxglove-sdk")}  # module, PyPI name


class Viewer(Protocol):
    """What the frame loop calls."""

    def log_step(self, frame: Frame, step: StepResult, slam: Slam) -> None:
        """Show the state after one processed frame."""
        ...

    def close(self) -> None:
        """Send what is still due (the final map) and flush; idempotent."""
        ...


@dataclass(frozen=True)
class ViewerOptions:
    """Which viewer, and where its stream goes.

    Attributes:
        kind: ``rerun`` or ``foxglove``.
        live: serve (or spawn) a live view.
        save: also record the stream to this file (``.rrd`` for rerun, ``.mcap`` for foxglove).
        host: address the live servers bind to.
        port: rerun gRPC port (default 9876) or Foxglove WebSocket port (default 8765).
        web_port: port of rerun's web viewer when no display is available (default 9090).
        settings: what is sent and how often.
    """

    kind: ViewerKind
    live: bool = True
    save: Path | None = None
    host: str = "127.0.0.1"
    port: int | None = None
    web_port: int | None = None
    settings: ViewerSettings = field(default_factory=ViewerSettings)

    def __post_init__(self) -> None:
        if self.kind not in VIEWER_KINDS:
            raise ConfigError(f"unknown viewer {self.kind!r}; choose one of {', '.join(VIEWER_KINDS)}")
        if not self.live and self.save is None:
            raise ConfigError("a viewer needs a live view or a file to record to")
        if self.save is not None and kind_of_file(self.save) != self.kind:
            wanted = next(ext for ext, kind in _EXTENSIONS.items() if kind == self.kind)
            raise ConfigError(f"the {self.kind} viewer records to a {wanted} file, got {self.save}")


def kind_of_file(path: Path) -> ViewerKind:
    """The backend that writes files like ``path`` (``.rrd`` rerun, ``.mcap`` foxglove)."""
    kind = _EXTENSIONS.get(path.suffix.lower())
    if kind is None:
        raise ConfigError(f"viewer recording {path}: use a .rrd (rerun) or .mcap (foxglove) file name")
    return kind


class StreamingViewer(abc.ABC):
    """Common part of the backends: snapshots, the final map on close, failure isolation."""

    def __init__(self, options: ViewerOptions) -> None:
        self.options = options
        self.recorder = SnapshotRecorder(options.settings)
        self.where: list[str] = []  # human-readable destinations, printed by the CLI
        self.steps = 0
        self._table: LabelTable | None = None
        self._last: tuple[Snapshot, Slam] | None = None
        self._failed = False
        self._closed = False

    def log_step(self, frame: Frame, step: StepResult, slam: Slam) -> None:
        """Capture and send one update (no-op after a failure or close)."""
        if self._failed or self._closed:
            return
        try:
            if self._table is None:
                self._table = slam.codec.table
                self.start(self._table)
            snap = self.recorder.capture(frame, step, slam)
            self.send(snap)
            self._last = (snap, slam)
            self.steps += 1
        except Exception as err:
            self._failed = True
            log.warning("%s viewer stopped after %d frames: %s", self.options.kind, self.steps, err)

    def close(self) -> None:
        """Send the final map if the last update did not carry it, then flush and close."""
        if self._closed:
            return
        self._closed = True
        try:
            if self._last is not None and not self._failed:
                snap, slam = self._last
                if snap.points is None:
                    points = self.recorder.map_points(slam)
                    if points is not None:
                        self.send_points(snap.index, snap.stamp_ns, points)
        finally:
            self.finish()

    # ------------------------------------------------------------------ backend interface
    @abc.abstractmethod
    def start(self, table: LabelTable) -> None:
        """Static data sent once, before the first update (class names and colours)."""

    @abc.abstractmethod
    def send(self, snap: Snapshot) -> None:
        """One update."""

    @abc.abstractmethod
    def send_points(self, index: int, stamp_ns: int, points: MapPoints) -> None:
        """The map's points alone (the final map)."""

    @abc.abstractmethod
    def finish(self) -> None:
        """Flush and release sinks."""


def check_port_free(host: str, port: int) -> None:
    """Raise :class:`BackendUnavailableError` when ``host:port`` cannot be bound (another viewer runs)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        try:
            sock.bind((host, port))
        except OSError as err:
            raise BackendUnavailableError(
                f"cannot serve the viewer on {host}:{port} ({err.strerror}); choose another with --viewer-port"
            ) from err


def open_viewer(options: ViewerOptions) -> StreamingViewer:
    """Start the chosen backend; a missing package raises :class:`BackendUnavailableError` with the fix."""
    module, package = _PACKAGES[options.kind]
    if importlib.util.find_spec(module) is None:
        raise BackendUnavailableError(
            f"--viewer {options.kind} needs the {package} package: "
            f"`pip install {package}` or `pip install 'sgs_slam_ros[viewer]'`"
        )
    if options.kind == "rerun":
        from sgs_slam_core.viz.rerun_viewer import RerunViewer  # noqa: PLC0415 - optional dependency

        return RerunViewer(options)
    from sgs_slam_core.viz.foxglove_viewer import FoxgloveViewer  # noqa: PLC0415 - optional dependency

    return FoxgloveViewer(options)
