"""The dataset protocol, reader options and the shared per-frame pipeline.

A reader lists :class:`FrameRecord` s (files, stamp, ground truth) and decodes one at native
resolution; :class:`RecordDataset` applies start / stride / max-frames and downscaling the same way
for every format.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol, runtime_checkable

import cv2
import numpy as np

from sgs_slam_core.errors import DatasetError, SgsSlamError
from sgs_slam_core.fileio import read_image
from sgs_slam_core.frame import Frame
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.labels import LabelTable

__all__ = [
    "CPU_WIDTH_PX",
    "MIN_IMAGE_SIDE",
    "Dataset",
    "DatasetOptions",
    "FrameRecord",
    "RecordDataset",
    "auto_downscale",
    "check_frame_size",
    "check_rigid",
    "read_color",
    "read_depth_png",
    "read_label_png",
    "resize_frame",
    "rigid_or_none",
]


MIN_IMAGE_SIDE = 16  # px: below this the SSIM window (11 px) and tracking have too little to work with
# ``downscale`` auto on a CPU: the processing width at which two cores track a 30 Hz camera live
# (BENCHMARKS.md: 160x120 keeps up with fr3/teddy, 320x240 tracks a third of its frames).
CPU_WIDTH_PX = 160


def auto_downscale(width: int, cpu: bool) -> float:
    """The ``auto`` downscale of images ``width`` px wide: on a CPU the factor to ~160 px (at least 1), else 1."""
    return max(1.0, width / CPU_WIDTH_PX) if cpu else 1.0


@dataclass(frozen=True)
class DatasetOptions:
    """Frame selection and resolution, identical for every format.

    Attributes:
        start: index of the first frame kept (after skipping frames without a usable pose).
        stride: keep every ``stride``-th frame from ``start``.
        max_frames: keep at most this many frames (None = all).
        downscale: divide width and height by this factor (1 = native); colour is area-averaged,
            depth and labels are taken nearest-neighbour so no depth or class is invented.
    """

    start: int = 0
    stride: int = 1
    max_frames: int | None = None
    downscale: float = 1.0

    def __post_init__(self) -> None:
        if self.start < 0 or self.stride < 1:
            raise DatasetError(f"need start >= 0 and stride >= 1, got start={self.start}, stride={self.stride}")
        if self.max_frames is not None and self.max_frames < 1:
            raise DatasetError(f"max_frames must be >= 1, got {self.max_frames}")
        if not self.downscale >= 1.0:
            raise DatasetError(f"downscale must be >= 1, got {self.downscale}")

    def select(self, n: int) -> range:
        """Indices of the kept frames among ``n``."""
        picked = range(self.start, n, self.stride)
        return picked if self.max_frames is None else picked[: self.max_frames]


@runtime_checkable
class Dataset(Protocol):
    """What the SLAM runner, the bag converter and the tests need from any source of frames."""

    name: str

    @property
    def intrinsics(self) -> Intrinsics:
        """Intrinsics of the frames as returned (after downscaling)."""
        ...

    @property
    def label_table(self) -> LabelTable:
        """Class ids, names and colours of the label images."""
        ...

    @property
    def has_ground_truth(self) -> bool:
        """True when at least one frame carries a ground-truth pose."""
        ...

    @property
    def has_labels(self) -> bool:
        """True when frames carry label images."""
        ...

    @property
    def stamps_ns(self) -> list[int]:
        """Time stamp of every frame (ns), without decoding any."""
        ...

    def ground_truth(self, index: int) -> np.ndarray | None:
        """Ground-truth c2w [4, 4] of frame ``index`` (None without), without decoding its images."""
        ...

    def __len__(self) -> int: ...

    def __getitem__(self, index: int) -> Frame: ...


@dataclass(frozen=True)
class FrameRecord:
    """Where one frame's data lives."""

    color: Path
    depth: Path
    stamp_ns: int
    labels: Path | None = None
    gt_c2w: np.ndarray | None = field(default=None, compare=False)  # [4, 4]


def read_color(path: Path) -> np.ndarray:  # [H, W, 3] uint8 RGB
    """An 8-bit colour image (any format OpenCV reads) as RGB."""
    img = read_image(path, cv2.IMREAD_COLOR, "colour")
    return np.ascontiguousarray(img[..., ::-1])


def _read_unchanged(path: Path, what: str) -> np.ndarray:
    img = read_image(path, cv2.IMREAD_UNCHANGED, what)
    if img.ndim != 2:
        raise DatasetError(f"{what} image {path} must have one channel, got shape {img.shape}")
    return img


def read_depth_png(path: Path, scale: float) -> np.ndarray:  # [H, W] float32 metres
    """A 16-bit depth PNG divided by ``scale`` (units per metre); 0 stays 0 (invalid)."""
    raw = _read_unchanged(path, "depth")
    if raw.dtype != np.uint16:
        raise DatasetError(f"depth image {path} must be 16-bit, got {raw.dtype}")
    return np.divide(raw, np.float32(scale), dtype=np.float32)  # one pass, same values as float32 / float32


def read_label_png(path: Path) -> np.ndarray:  # [H, W] int32
    """An 8- or 16-bit class-id image."""
    raw = _read_unchanged(path, "label")
    if raw.dtype not in (np.uint8, np.uint16):
        raise DatasetError(f"label image {path} must be 8- or 16-bit, got {raw.dtype}")
    return raw.astype(np.int32)


def check_frame_size(k: Intrinsics, options: DatasetOptions) -> None:
    """Refuse a ``downscale`` that leaves frames smaller than :data:`MIN_IMAGE_SIDE` (native sizes are the data's)."""
    if options.downscale != 1.0 and min(k.width, k.height) < MIN_IMAGE_SIDE:
        raise DatasetError(
            f"downscale {options.downscale:g} leaves {k.width}x{k.height} px frames; "
            f"SLAM and its metrics need at least {MIN_IMAGE_SIDE}x{MIN_IMAGE_SIDE}"
        )


def rigid_or_none(matrix: np.ndarray, where: str, tolerance: float = 1e-3) -> np.ndarray | None:  # [4, 4]
    """A ground-truth camera-to-world matrix, None when it is not finite (a frame without ground truth).

    A finite matrix that is not a rigid transform (rotation orthonormal with determinant +1 within
    ``tolerance``, last row 0 0 0 1) raises :class:`DatasetError` naming ``where``.
    """
    if matrix.shape != (4, 4):
        raise DatasetError(f"{where}: expected a 4x4 matrix, got shape {matrix.shape}")
    if not np.isfinite(matrix).all():
        return None
    return check_rigid(matrix, where, DatasetError, tolerance)


def check_rigid(
    matrix: np.ndarray, where: str, error: type[SgsSlamError], tolerance: float = 1e-3
) -> np.ndarray:  # [4, 4]
    """``matrix`` when it is a finite rigid transform, else ``error`` naming ``where`` and what is wrong.

    Rigid: rotation part orthonormal with determinant +1 within ``tolerance``, last row 0 0 0 1.
    """
    if not np.isfinite(matrix).all():
        raise error(f"{where}: the matrix holds NaN or inf")
    r = matrix[:3, :3]
    if not np.allclose(matrix[3], [0.0, 0.0, 0.0, 1.0], atol=1e-6):
        raise error(f"{where}: not a rigid transform (the last row must be 0 0 0 1, got {matrix[3].tolist()})")
    if np.abs(r @ r.T - np.eye(3)).max() > tolerance or np.linalg.det(r) < 0:
        raise error(f"{where}: not a rigid transform (the rotation part is not a rotation: orthonormal, det +1)")
    return matrix


def resize_frame(
    rgb: np.ndarray, depth: np.ndarray, labels: np.ndarray | None, width: int, height: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Bring colour (area/bilinear), depth and labels (nearest) to ``width`` x ``height``."""
    if rgb.shape[:2] != (height, width):
        shrink = rgb.shape[1] > width
        rgb = cv2.resize(rgb, (width, height), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
    if depth.shape != (height, width):
        depth = cv2.resize(depth, (width, height), interpolation=cv2.INTER_NEAREST)
    if labels is not None and labels.shape != (height, width):
        labels = cv2.resize(labels, (width, height), interpolation=cv2.INTER_NEAREST)
    return rgb, depth, labels


class RecordDataset:
    """A dataset made of :class:`FrameRecord` s; subclasses fill ``records`` and the camera."""

    name: str = "dataset"

    def __init__(
        self,
        records: Sequence[FrameRecord],
        native: Intrinsics,
        depth_scale: float,
        label_table: LabelTable,
        options: DatasetOptions,
    ) -> None:
        self.options = options
        self._records = [records[i] for i in options.select(len(records))]
        if not self._records:
            raise DatasetError(f"{self.name}: no frames left after start={options.start}, stride={options.stride}")
        self._native = native
        self._depth_scale = depth_scale
        self._table = label_table
        self._intrinsics = native if options.downscale == 1.0 else native.scaled(1.0 / options.downscale)
        check_frame_size(self._intrinsics, options)

    @property
    def intrinsics(self) -> Intrinsics:
        """Intrinsics after downscaling."""
        return self._intrinsics

    @property
    def label_table(self) -> LabelTable:
        """Class table of the label images."""
        return self._table

    @property
    def has_ground_truth(self) -> bool:
        """True when at least one kept frame has a ground-truth pose."""
        return any(r.gt_c2w is not None for r in self._records)

    @property
    def has_labels(self) -> bool:
        """True when the kept frames carry label images."""
        return self._records[0].labels is not None

    @property
    def records(self) -> list[FrameRecord]:
        """The kept frames' records."""
        return list(self._records)

    @property
    def stamps_ns(self) -> list[int]:
        """Time stamp of every kept frame (ns)."""
        return [r.stamp_ns for r in self._records]

    def ground_truth(self, index: int) -> np.ndarray | None:
        """Ground-truth c2w [4, 4] of kept frame ``index``, or None."""
        gt = self._records[index].gt_c2w
        return None if gt is None else gt.copy()

    def __len__(self) -> int:
        return len(self._records)

    def __iter__(self) -> Iterator[Frame]:
        return (self[i] for i in range(len(self)))

    def __getitem__(self, index: int) -> Frame:
        if not -len(self) <= index < len(self):
            raise IndexError(f"frame {index} out of range for {len(self)} frames")
        index %= len(self)
        rec = self._records[index]
        rgb, depth, labels = self.decode(rec)
        k = self._intrinsics
        rgb, depth, labels = resize_frame(rgb, depth, labels, k.width, k.height)
        return Frame(
            rgb=rgb,
            depth=depth,
            intrinsics=k,
            labels=labels,
            stamp_ns=rec.stamp_ns,
            gt_c2w=rec.gt_c2w,
            index=index,
        )

    def decode(self, rec: FrameRecord) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Colour, depth (m) and labels of a record at the native camera resolution."""
        rgb = read_color(rec.color)
        depth = read_depth_png(rec.depth, self._depth_scale)
        labels = read_label_png(rec.labels) if rec.labels is not None else None
        h, w = self._native.shape
        if depth.shape != (h, w):
            raise DatasetError(f"depth image {rec.depth} is {depth.shape[1]}x{depth.shape[0]}, camera says {w}x{h}")
        return rgb, depth, labels
