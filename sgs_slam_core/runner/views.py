"""Render a saved map from given cameras and write the images (colour, 16-bit depth, semantic colours)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from sgs_slam_core.config import build
from sgs_slam_core.config.loader import known_keys
from sgs_slam_core.config.schema import SlamConfig
from sgs_slam_core.errors import ShapeError
from sgs_slam_core.fileio import make_dir, write_image
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.kernels import render
from sgs_slam_core.mapio.native import MapFile
from sgs_slam_core.render.output import RenderOutput
from sgs_slam_core.render.settings import RenderSettings
from sgs_slam_core.semantics import SemanticCodec, SemanticSettings

__all__ = ["MapViews", "default_intrinsics"]


def default_intrinsics(width: int, height: int, hfov_deg: float = 60.0) -> Intrinsics:
    """A pinhole camera of ``width`` x ``height`` px with horizontal field of view ``hfov_deg``."""
    if width < 1 or height < 1 or not 0 < hfov_deg < 180:
        raise ShapeError(f"bad camera: {width}x{height} px, hfov {hfov_deg} deg")
    f = 0.5 * width / math.tan(math.radians(hfov_deg) / 2)
    return Intrinsics(f, f, (width - 1) / 2, (height - 1) / 2, width, height)


@dataclass
class MapViews:
    """A saved map ready to render: its render settings and semantic decoding come from its config."""

    saved: MapFile
    device: torch.device

    def __post_init__(self) -> None:
        config = build(SlamConfig, known_keys(SlamConfig, self.saved.config)) if self.saved.config else None
        s = self.saved.gaussians.num_semantic
        if config is not None and (config.semantic.mode == "color") == (s == 3):
            semantic = config.semantic
        else:  # a PLY: infer the encoding from the channel count
            semantic = SemanticSettings("color") if s == 3 else SemanticSettings("onehot", max(s, 2))
        self.settings: RenderSettings = config.render if config is not None else RenderSettings()
        self.codec = SemanticCodec(semantic, self.saved.label_table)
        self.gaussians = self.saved.gaussians.to(self.device)
        self.candidates = sorted({0, *(int(i) for i in self.gaussians.labels.unique())})

    def intrinsics(self, width: int | None, height: int | None) -> Intrinsics:
        """The map's camera resized to ``width`` x ``height`` (either may be None), else a 60 degree one."""
        k = self.saved.intrinsics
        if k is None:
            return default_intrinsics(width or 640, height or 480)
        if width is None and height is None:
            return k
        w = width or round(k.width * height / k.height)  # type: ignore[operator]
        h = height or round(k.height * w / k.width)
        return k.resized(w, h)

    @torch.no_grad()
    def render(self, c2w: np.ndarray, k: Intrinsics, semantic: bool) -> RenderOutput:
        """One view from a camera-to-world pose [4, 4]."""
        w2c = torch.as_tensor(np.linalg.inv(c2w), dtype=torch.float32, device=self.device)
        return render(self.gaussians, k, w2c, self.settings, with_semantics=semantic and self.codec.num_channels > 0)

    def write(self, poses: Sequence[np.ndarray], k: Intrinsics, out_dir: Path, semantic: bool) -> list[Path]:
        """Write ``color_NNNNN.png``, ``depth_NNNNN.png`` (uint16 mm) and, with ``semantic``, the classes.

        ``semantic_NNNNN.png`` holds the classes' colours, ``labels_NNNNN.png`` their ids (uint16, 0 where
        nothing is mapped), which any tool can score against its own ground truth.
        """
        make_dir(out_dir)
        written = []
        for i, c2w in enumerate(poses):
            out = self.render(c2w, k, semantic)
            rgb = (out.color.clamp(0, 1).cpu().numpy() * 255).round().astype(np.uint8)
            depth = np.nan_to_num(out.depth.cpu().numpy(), nan=0.0, posinf=0.0)
            depth_mm = np.clip(np.round(depth * 1000), 0, 65535).astype(np.uint16)
            paths = [out_dir / f"color_{i:05d}.png", out_dir / f"depth_{i:05d}.png"]
            write_image(paths[0], rgb[..., ::-1])  # atomic: a failed write leaves no partial PNG
            write_image(paths[1], depth_mm)
            if semantic:
                labels = self.codec.decode_image(out.semantic, self.candidates).cpu().numpy()
                labels[out.silhouette.cpu().numpy() < 0.5] = 0
                paths.append(out_dir / f"semantic_{i:05d}.png")
                write_image(paths[-1], self.saved.label_table.colorize(labels)[..., ::-1])
                paths.append(out_dir / f"labels_{i:05d}.png")
                write_image(paths[-1], np.clip(labels, 0, 65535).astype(np.uint16))
            written += paths
        return written
