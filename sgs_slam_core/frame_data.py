"""Frames as tensors on the compute device."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import cv2
import numpy as np
import torch
from torch import Tensor

from sgs_slam_core.frame import CompactFrame, Frame
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.semantics import SemanticCodec

__all__ = ["FrameTensors", "resize_arrays"]


@dataclass(frozen=True)
class FrameTensors:
    """One frame ready for rendering losses (all on one device); ``with_ignore`` makes a copy with new edit locks."""

    index: int
    intrinsics: Intrinsics
    rgb: Tensor  # [H, W, 3] float32 in [0, 1]
    depth: Tensor  # [H, W] float32 m, 0 = invalid
    labels: Tensor | None  # [H, W] int64
    semantic: Tensor | None  # [H, W, S] float32 target of the semantic channels
    ignore: Tensor | None = None  # [H, W] bool, pixels left out of every loss and of densification (edit locks)
    _valid: Tensor | None = field(default=None, init=False, repr=False, compare=False)

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
        ids = (int(labels.min()), int(labels.max())) if labels is not None and labels.size else None  # on the host
        return FrameTensors(
            index=index,
            intrinsics=intrinsics,
            rgb=torch.from_numpy(rgb).to(device).float() / 255.0,
            depth=torch.from_numpy(depth.astype(np.float32)).to(device),
            labels=lab,
            semantic=codec.encode(lab, ids) if lab is not None else None,
        )

    @staticmethod
    def from_frame(frame: Frame, codec: SemanticCodec, device: torch.device) -> FrameTensors:
        """Upload and encode a :class:`Frame`."""
        return FrameTensors.from_arrays(
            frame.index, frame.intrinsics, frame.rgb, frame.depth, frame.labels, codec, device
        )

    @staticmethod
    def from_compact(kf: CompactFrame, codec: SemanticCodec, device: torch.device) -> FrameTensors:
        """A stored keyframe back on the device, for a mapping iteration."""
        return FrameTensors.from_arrays(kf.index, kf.intrinsics, kf.rgb, kf.depth_m, kf.labels, codec, device)

    @property
    def valid(self) -> Tensor:  # [H, W] bool
        """Pixels with a depth measurement that are not ignored.

        Computed once per frame (a mapping window asks about a hundred times a frame).
        """
        if self._valid is None:
            mask = self.depth > 0 if self.ignore is None else (self.depth > 0) & ~self.ignore
            object.__setattr__(self, "_valid", mask)  # a cache of immutable inputs, not a change of the frame
        return self._valid

    def with_ignore(self, ignore: Tensor | None) -> FrameTensors:  # ignore [H, W] bool
        """This frame with ``ignore`` as its ignored pixels (the edit locks at the time of use)."""
        return dataclasses.replace(self, ignore=ignore)

    def with_index(self, index: int) -> FrameTensors:
        """This frame numbered ``index`` (the SLAM's frame counter)."""
        return dataclasses.replace(self, index=index)


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
