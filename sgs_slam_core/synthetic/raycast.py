"""Render colour, depth and labels of a scene by analytic ray casting (no Gaussians involved)."""

from __future__ import annotations

import cv2
import numpy as np

from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.synthetic.primitives import Rays
from sgs_slam_core.synthetic.room import Scene

__all__ = ["raycast"]


def _cast(scene: Scene, origin: np.ndarray, dirs: np.ndarray, seed: int) -> tuple[np.ndarray, ...]:
    """Nearest hit per ray: (t [R], colour [R, 3], label [R], primitive index [R])."""
    rays = Rays(dirs)
    ts = np.stack([p.intersect(origin, rays) for p in scene.primitives])  # [P, R]
    which = ts.argmin(axis=0)
    t = ts[which, np.arange(dirs.shape[0])]
    colour = np.zeros((dirs.shape[0], 3))
    labels = np.zeros(dirs.shape[0], dtype=np.int32)
    for k, prim in enumerate(scene.primitives):
        sel = np.nonzero((which == k) & np.isfinite(t))[0]
        if sel.size == 0:
            continue
        points = origin + t[sel, None] * dirs[sel]
        colour[sel] = prim.colors_at(points, prim.normal(points), seed)
        labels[sel] = prim.labels_at(points)
    return t, colour, labels, which


def _camera_rays(intrinsics: Intrinsics, rot: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:  # [R, 3]
    """World directions (x/z, y/z, 1) rotated by ``rot``: the ray parameter equals camera depth."""
    cam = np.stack([(u - intrinsics.cx) / intrinsics.fx, (v - intrinsics.cy) / intrinsics.fy, np.ones_like(u)], 1)
    return cam @ rot.T


def raycast(
    scene: Scene, intrinsics: Intrinsics, c2w: np.ndarray, supersample: int = 2, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(rgb [H, W, 3] uint8, depth [H, W] float32 m, labels [H, W] int32)``.

    Depth and labels come from the ray through each pixel centre. Colour is anti-aliased where it
    matters: pixels on a silhouette (a neighbour sees another primitive) average ``supersample``^2
    sub-pixel rays (box filter), as a real sensor integrates over the pixel; elsewhere the smooth
    textures are sampled at the centre.
    """
    h, w = intrinsics.shape
    rot, origin = c2w[:3, :3], c2w[:3, 3]
    v, u = np.meshgrid(np.arange(h, dtype=np.float64), np.arange(w, dtype=np.float64), indexing="ij")
    t, colour, labels, which = _cast(scene, origin, _camera_rays(intrinsics, rot, u.ravel(), v.ravel()), seed)
    if supersample > 1:
        ids = which.reshape(h, w).astype(np.float32)
        kernel = np.ones((3, 3), np.uint8)
        edge = (cv2.dilate(ids, kernel) != cv2.erode(ids, kernel)).ravel()
        if edge.any():
            offsets = (np.arange(supersample) + 0.5) / supersample - 0.5
            ou, ov = (o.ravel() for o in np.meshgrid(offsets, offsets, indexing="xy"))
            eu = (u.ravel()[edge][:, None] + ou).ravel()
            ev = (v.ravel()[edge][:, None] + ov).ravel()
            _, sub, _, _ = _cast(scene, origin, _camera_rays(intrinsics, rot, eu, ev), seed)
            colour[edge] = sub.reshape(-1, supersample * supersample, 3).mean(axis=1)
    depth = np.where(np.isfinite(t), t, 0.0).reshape(h, w).astype(np.float32)
    rgb = np.clip(np.round(colour.reshape(h, w, 3) * 255), 0, 255).astype(np.uint8)
    return rgb, depth, labels.reshape(h, w)
