"""Frames as tensors on the compute device, and their compact host copies (keyframes)."""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
import torch
from torch import Tensor

from sgs_slam_core.frame import Frame
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.semantics import SemanticCodec

__all__ = ["DEPTH_UNITS_PER_M", "CompactFrame", "FrameTensors", "compact_labels"]

DEPTH_UNITS_PER_M = 5000.0  # compact depth: uint16 in 0.2 mm steps, up to 13.1 m


@dataclass
class FrameTensors:
    """One frame ready for rendering losses (all on one device)."""

    index: int
    intrinsics: Intrinsics
    rgb: Tensor  # [H, W, 3] float32 in [0, 1]
    depth: Tensor  # [H, W] float32 m, 0 = invalid
    labels: Tensor | None  # [H, W] int64
    semantic: Tensor | None  # [H, W, S] float32 target of the semantic channels
    ignore: Tensor | None = None  # [H, W] bool, pixels left out of every loss and of densification (edit locks)
    _valid: tuple[Tensor, Tensor | None, Tensor] | None = field(default=None, init=False, repr=False, compare=False)

    @staticmethod
    def from_arrays(
        index: int,
        intrinsics: Intrinsics,
        rgb: np.ndarray,
        depth: np.ndarray,
        labels: np.ndarray | None,
        codec: SemanticCodec,
        device: torch.device,
    ) -> FrameTensors:
        """Upload and encode one frame's arrays."""
        lab = torch.from_numpy(labels.astype(np.int64)).to(device) if labels is not None else None
        return FrameTensors(
            index=index,
            intrinsics=intrinsics,
            rgb=torch.from_numpy(rgb).to(device).float() / 255.0,
            depth=torch.from_numpy(depth.astype(np.float32)).to(device),
            labels=lab,
            semantic=codec.encode(lab) if lab is not None else None,
        )

    @staticmethod
    def from_frame(frame: Frame, codec: SemanticCodec, device: torch.device) -> FrameTensors:
        """Upload and encode a :class:`Frame`."""
        return FrameTensors.from_arrays(
            frame.index, frame.intrinsics, frame.rgb, frame.depth, frame.labels, codec, device
        )

    @property
    def valid(self) -> Tensor:  # [H, W] bool
        """Pixels with a depth measurement that are not ignored.

        Kept for the ``depth`` and ``ignore`` it was made from (a mapping window asks ~100 times a frame).
        """
        cached = self._valid
        if cached is None or cached[0] is not self.depth or cached[1] is not self.ignore:
            mask = self.depth > 0 if self.ignore is None else (self.depth > 0) & ~self.ignore
            self._valid = cached = (self.depth, self.ignore, mask)
        return cached[2]


def compact_labels(labels: np.ndarray) -> np.ndarray:  # [H, W] uint8, uint16 or int32
    """Class ids in the smallest integer type that holds them (uint8 for NYU40 or Replica ids)."""
    if labels.size == 0 or (labels.min() >= 0 and labels.max() < 2**8):
        return labels.astype(np.uint8)
    if labels.min() >= 0 and labels.max() < 2**16:
        return labels.astype(np.uint16)
    return labels.astype(np.int32)


@dataclass
class CompactFrame:
    """A keyframe kept on the host: uint8 colour, uint16 depth (0.2 mm), compact labels, its pose."""

    index: int
    stamp_ns: int
    intrinsics: Intrinsics
    rgb: np.ndarray  # [H, W, 3] uint8
    depth: np.ndarray  # [H, W] uint16, DEPTH_UNITS_PER_M per metre
    labels: np.ndarray | None  # [H, W] uint8 (ids < 256), uint16 (< 65536) or int32
    w2c: np.ndarray  # [4, 4] float64, the estimate at insertion (not refined later, as the reference)

    @staticmethod
    def from_frame(frame: Frame, w2c: np.ndarray) -> CompactFrame:
        """Compress a frame (depth beyond 13.1 m becomes invalid)."""
        units = np.round(frame.depth * DEPTH_UNITS_PER_M)
        depth = np.where(units <= 65535, units, 0).astype(np.uint16)
        return CompactFrame(frame.index, frame.stamp_ns, frame.intrinsics, frame.rgb.copy(), depth,
                            None if frame.labels is None else compact_labels(frame.labels), w2c.copy())  # fmt: skip

    @property
    def depth_m(self) -> np.ndarray:  # [H, W] float32
        """Depth in metres."""
        return self.depth.astype(np.float32) / np.float32(DEPTH_UNITS_PER_M)

    def to_tensors(self, codec: SemanticCodec, device: torch.device) -> FrameTensors:
        """Back to device tensors for a mapping iteration."""
        return FrameTensors.from_arrays(self.index, self.intrinsics, self.rgb, self.depth_m, self.labels, codec, device)

    @property
    def nbytes(self) -> int:
        """Host memory held by this keyframe."""
        return self.rgb.nbytes + self.depth.nbytes + (self.labels.nbytes if self.labels is not None else 0)


def resize_arrays(
    rgb: np.ndarray, depth: np.ndarray, labels: np.ndarray | None, intrinsics: Intrinsics, scale: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, Intrinsics]:
    """A frame's arrays at ``scale`` x resolution (colour area, depth and labels nearest)."""
    k = intrinsics.scaled(scale)
    size = (k.width, k.height)
    rgb = cv2.resize(rgb, size, interpolation=cv2.INTER_AREA)
    depth = cv2.resize(depth, size, interpolation=cv2.INTER_NEAREST)
    labels = cv2.resize(labels, size, interpolation=cv2.INTER_NEAREST) if labels is not None else None
    return rgb, depth, labels, k
