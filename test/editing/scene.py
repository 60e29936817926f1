"""A hand-built labelled map: a wall, a box in front of it, and two chairs of the same class."""

from __future__ import annotations

import math

import numpy as np
import torch

from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.kernels import render
from sgs_slam_core.labels import LabelTable
from sgs_slam_core.render.output import RenderOutput
from sgs_slam_core.semantics import SemanticCodec, SemanticSettings

WALL, BOX, CHAIR = 1, 5, 6  # NYU40: wall, chair... ids only matter through the table's colours
TABLE = LabelTable.nyu40()
CODEC = SemanticCodec(SemanticSettings("color"), TABLE)
K = Intrinsics(fx=60.0, fy=60.0, cx=31.5, cy=23.5, width=64, height=48)
W2C = torch.eye(4)  # camera at the origin looking down +z (OpenCV)
BOX_Z = 2.0  # m


def _patch(x0: float, x1: float, y0: float, y1: float, z: float, step: float) -> np.ndarray:  # [M, 3]
    xs = np.arange(x0, x1 + 1e-9, step)
    ys = np.arange(y0, y1 + 1e-9, step)
    gx, gy = np.meshgrid(xs, ys, indexing="xy")
    return np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, z)], axis=1)


def _part(points: np.ndarray, radius: float, label: int, rgb: tuple[float, float, float]) -> GaussianMap:
    n = len(points)
    return GaussianMap(
        means=torch.tensor(points, dtype=torch.float32),
        log_scales=torch.full((n, 1), math.log(radius)),
        logit_opacities=torch.full((n,), 4.0),
        colors=torch.tensor(rgb).expand(n, 3).clone(),
        semantics=CODEC.encode(torch.full((n,), label)),
        labels=torch.full((n,), label, dtype=torch.int64),
        birth_frame=torch.arange(n, dtype=torch.int64),
    )


def labelled_scene() -> GaussianMap:
    """Wall (z = 3 m), a 0.6 m box at z = 2 m in the middle, a big chair left and a small chair right."""
    wall = _part(_patch(-1.8, 1.8, -1.3, 1.3, 3.0, 0.05), 0.04, WALL, (0.8, 0.8, 0.7))
    box = _part(_patch(-0.3, 0.3, -0.3, 0.3, BOX_Z, 0.02), 0.015, BOX, (0.9, 0.1, 0.1))
    big_chair = _part(_patch(-1.5, -0.9, -0.2, 0.6, 2.5, 0.03), 0.02, CHAIR, (0.1, 0.3, 0.9))
    small_chair = _part(_patch(0.8, 1.1, 0.1, 0.5, 2.5, 0.03), 0.02, CHAIR, (0.1, 0.3, 0.9))
    return wall.cat(box).cat(big_chair).cat(small_chair)


def draw(gaussians: GaussianMap) -> tuple[RenderOutput, torch.Tensor]:
    """Render from the fixed camera; returns the output and the decoded label image [H, W]."""
    out = render(gaussians, K, W2C)
    labels = CODEC.decode(out.semantic, [0, WALL, BOX, CHAIR])
    labels = torch.where(out.silhouette > 0.5, labels, torch.zeros_like(labels))
    return out, labels
