"""Assemble synchronised RGB, depth and camera_info messages into core Frames; label images apart.

Bad input never raises out of a callback: each cause is logged once (with a running count),
counted for /diagnostics, and the frame is dropped. Every colour image is accounted for: it becomes
a frame, is dropped by the synchroniser (no partner in time, or pushed out of its queue), is
rejected (bad input), or still waits (``colour_in == emitted + colour_dropped + rejected + waiting``).
With a ``downscale`` above 1 each frame is brought to the processing size exactly as ``sgs-slam run
--downscale`` does (colour area-averaged, depth and labels nearest, intrinsics scaled); ``auto``
(0) picks the factor from the camera's width at the first image
(``sgs_slam_core.datasets.base.auto_downscale``: 160 px wide on a CPU, the input size on a GPU).

Label images are not synchronised with the frames: a segmenter is slower than the camera and behind
it, and a frame that waited for its labels would wait out the segmenter. Each label image is checked
against the camera's size, brought to the processing size and handed to ``on_labels`` with its
stamp, to be fused into the map when it comes.
"""

from __future__ import annotations

import threading
from collections import Counter
from collections.abc import Callable
from typing import Any

import cv2
import numpy as np

from msg_adapters import (
    AdapterError,
    ApproximateSync,
    camera_info_to_intrinsics,
    depth_from_image,
    labels_from_image,
    rgb_from_image,
    stamp_to_ns,
)
from sgs_slam_core.datasets.base import CPU_WIDTH_PX, MIN_IMAGE_SIDE, auto_downscale, resize_frame
from sgs_slam_core.errors import SgsSlamError
from sgs_slam_core.frame import Frame
from sgs_slam_core.geometry.camera import Intrinsics

__all__ = ["AUTO_DOWNSCALE", "FrameAssembler"]

RGB, DEPTH = 0, 1
AUTO_DOWNSCALE = 0.0  # the downscale that is chosen from the camera's width


class _RejectedError(Exception):
    """A synchronised set that cannot become a Frame (internal: turned into a counted rejection)."""

    def __init__(self, cause: str, detail: str = "") -> None:
        super().__init__(cause)
        self.cause, self.detail = cause, detail


class FrameAssembler:
    """Turns incoming messages into Frames via an approximate-time synchroniser, and label images into label arrays.

    ``on_labels(stamp_ns, labels)``: a label image's class ids [H, W] at the processing size.
    """

    def __init__(
        self,
        queue_size: int,
        slop_ns: int,
        depth_scale: float,
        on_frame: Callable[[Frame], None],
        log: Callable[[str], None],
        downscale: float = 1.0,
        on_labels: Callable[[int, np.ndarray], None] | None = None,
        cpu: bool = True,
    ) -> None:
        self.on_labels = on_labels
        self.downscale = downscale  # AUTO_DOWNSCALE until the first image meets a camera_info
        self.cpu = cpu  # what auto chooses for
        self.input_size: tuple[int, int] | None = None  # (width, height) of the latest frame as received
        self.processing_size: tuple[int, int] | None = None  # and as handed on
        self.depth_scale = depth_scale
        self.on_frame, self.log = on_frame, log
        self.sync = ApproximateSync(2, queue_size, slop_ns)
        self.intrinsics: Intrinsics | None = None
        self.last_stamp_ns: int | None = None
        self.rejected: Counter[str] = Counter()
        self._logged: set[str] = set()
        self._lock = threading.Lock()
        self._waiting: list[tuple[int, list[Any]]] = []  # synchronised sets that arrived before any camera_info
        self._labels_waiting: list[Any] = []  # label images that arrived before any camera_info
        self._queue_size = queue_size
        self.frame_id = ""  # header.frame_id of the latest colour image that became a frame
        self.colour_in = 0  # colour images received
        self._waiting_dropped = 0  # sets waiting for camera_info dropped by a reset

    @property
    def colour_dropped(self) -> int:
        """Colour images dropped unmatched by the synchroniser, or by a reset while waiting."""
        with self._lock:
            return self.sync.dropped_by_input[RGB] + self._waiting_dropped

    @property
    def frames_waiting(self) -> int:
        """Colour images held by the synchroniser or waiting for camera_info."""
        with self._lock:
            return self.sync.pending(RGB) + len(self._waiting)

    @property
    def frames_rejected(self) -> int:
        """Synchronised sets dropped as bad input."""
        return sum(self.rejected.values())

    def set_slop(self, slop_s: float) -> None:
        """Change the synchroniser's tolerance (s) live."""
        with self._lock:
            self.sync.slop_ns = round(slop_s * 1e9)

    def reject(self, cause: str, detail: str = "") -> None:
        """Count a dropped input; log the first time this cause occurs."""
        self.rejected[cause] += 1
        if cause not in self._logged:
            self._logged.add(cause)
            self.log(f"dropping input: {cause}{': ' + detail if detail else ''} (counted in /diagnostics, logged once)")

    def camera_info(self, msg: Any) -> None:
        """Remember the latest intrinsics (assumed to stay valid until the next camera_info)."""
        try:
            k, warnings = camera_info_to_intrinsics(msg)
        except AdapterError as err:
            self.reject("bad camera_info", str(err))
            return
        for text in warnings:
            if text not in self._logged:
                self._logged.add(text)
                self.log(text)
        self.intrinsics = k
        with self._lock:
            waiting, self._waiting = self._waiting, []
            labels, self._labels_waiting = self._labels_waiting, []
        for stamp_ns, msgs in waiting:
            self._assemble(stamp_ns, msgs)
        for label_msg in labels:
            self._label(label_msg, k)

    def label_image(self, msg: Any) -> None:
        """A label image: checked against the camera's size, brought to the processing size, handed on.

        One that comes before any camera_info waits for it (as frames do), up to ``queue_size``.
        """
        with self._lock:
            k = self.intrinsics
            if k is None:
                self._labels_waiting.append(msg)
                overflow = len(self._labels_waiting) > self._queue_size
                if overflow:
                    self._labels_waiting.pop(0)
        if k is None:
            if overflow:
                self.reject("no camera_info yet", "waiting for rgb/camera_info")
            return
        self._label(msg, k)

    def _label(self, msg: Any, k: Intrinsics) -> None:
        try:
            labels = labels_from_image(msg)
        except AdapterError as err:
            self.reject("wrong encoding or bad image", str(err))
            return
        if labels.shape != k.shape:
            self.reject(
                "label image size differs", f"{labels.shape[1]}x{labels.shape[0]} vs camera {k.width}x{k.height}"
            )
            return
        if self._factor(k) != 1.0:
            size = k.scaled(1.0 / self.downscale)
            labels = cv2.resize(labels, (size.width, size.height), interpolation=cv2.INTER_NEAREST)
        if self.on_labels is not None:
            self.on_labels(stamp_to_ns(msg.header.stamp), labels)

    def auto_text(self) -> str:
        """What ``auto`` chooses here, for the start line."""
        return f"a width of {CPU_WIDTH_PX} px on the CPU" if self.cpu else "the input size on the GPU"

    def _factor(self, k: Intrinsics) -> float:
        """The downscale for camera ``k``; ``auto`` is chosen from its width the first time."""
        if self.downscale == AUTO_DOWNSCALE:
            self.downscale = auto_downscale(k.width, self.cpu)
        return self.downscale

    def image(self, index: int, msg: Any) -> None:
        """An rgb (0) or depth (1) image."""
        with self._lock:
            self.colour_in += int(index == RGB)
            matched = self.sync.push(index, stamp_to_ns(msg.header.stamp), msg)
        if matched is not None:
            self._assemble(*matched)

    def _assemble(self, stamp_ns: int, msgs: list[Any]) -> None:
        if self.intrinsics is None:  # topics arrive in any order: hold the set until camera_info comes
            with self._lock:
                self._waiting.append((stamp_ns, msgs))
                overflow = len(self._waiting) > self._queue_size
                if overflow:
                    self._waiting.pop(0)
            if overflow:
                self.reject("no camera_info yet", "waiting for rgb/camera_info")
            return
        try:
            frame = self._build(stamp_ns, msgs, self.intrinsics)
        except _RejectedError as rejected:
            self.reject(rejected.cause, rejected.detail)
            return
        self.last_stamp_ns = stamp_ns
        self.frame_id = msgs[RGB].header.frame_id
        self.on_frame(frame)

    def _build(self, stamp_ns: int, msgs: list[Any], k: Intrinsics) -> Frame:
        """The Frame of one synchronised set; raises :class:`_RejectedError` naming the cause."""
        if self.last_stamp_ns is not None and stamp_ns < self.last_stamp_ns:
            raise _RejectedError(
                "stamps went backwards",
                f"{stamp_ns} < {self.last_stamp_ns} ns (a replay started again? call ~/reset first, "
                "e.g. bag_player --reset)",
            )
        try:
            rgb = rgb_from_image(msgs[RGB])
            depth = depth_from_image(msgs[DEPTH], self.depth_scale)
        except AdapterError as err:
            raise _RejectedError("wrong encoding or bad image", str(err)) from err
        shapes = {"rgb": rgb.shape[:2], "depth": depth.shape}
        if len(set(shapes.values())) > 1:
            raise _RejectedError("image sizes differ", ", ".join(f"{n} {v[1]}x{v[0]}" for n, v in shapes.items()))
        if rgb.shape[:2] != k.shape:
            raise _RejectedError(
                "camera_info does not match the images", f"{k.width}x{k.height} vs {rgb.shape[1]}x{rgb.shape[0]}"
            )
        if not np.any(depth > 0):
            raise _RejectedError("depth image has no valid pixel")
        self.input_size = (k.width, k.height)
        if self._factor(k) != 1.0:
            k = k.scaled(1.0 / self.downscale)
            if min(k.width, k.height) < MIN_IMAGE_SIDE:
                raise _RejectedError(
                    "downscale leaves too small a frame",
                    f"{self.input_size[0]}x{self.input_size[1]} / {self.downscale:g} = {k.width}x{k.height}; "
                    f"SLAM needs at least {MIN_IMAGE_SIDE}x{MIN_IMAGE_SIDE}",
                )
            rgb, depth, _ = resize_frame(rgb, depth, None, k.width, k.height)
        self.processing_size = (k.width, k.height)
        try:
            return Frame(rgb=rgb, depth=depth, intrinsics=k, stamp_ns=stamp_ns)
        except SgsSlamError as err:
            raise _RejectedError("invalid frame", str(err)) from err

    def reset(self) -> None:
        """Forget queued messages and the last stamp (after a SLAM reset)."""
        with self._lock:
            self.sync.clear()
            self._waiting_dropped += len(self._waiting)
            self._waiting.clear()
            self._labels_waiting.clear()
        self.last_stamp_ns = None
