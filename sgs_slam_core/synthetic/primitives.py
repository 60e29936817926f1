"""Analytic ray intersections: boxes (yawed), spheres, vertical cylinders, and a room shell.

All rays of a pinhole camera share one origin, so ``intersect(origin [3], rays) -> t [R]`` takes
the origin once and a :class:`Rays` bundle (directions by column, inverses cached). It returns the
smallest positive ray parameter (inf on a miss); ``normal(points [R, 3]) -> [R, 3]`` gives unit
normals at hit points. Rays need not be normalised: with camera rays (x/z, y/z, 1) rotated to the
world, t is the camera-frame depth.
"""

from __future__ import annotations

import abc
import functools
from dataclasses import dataclass

import numpy as np

from sgs_slam_core.synthetic.textures import Material, shade

__all__ = ["Box", "Cylinder", "Primitive", "Rays", "RoomShell", "Sphere"]

_EPS = 1e-6


class Rays:
    """Ray directions ``[R, 3]`` with per-axis columns and their inverses (cached per yaw)."""

    def __init__(self, dirs: np.ndarray) -> None:
        self.dirs = dirs
        self.cols = tuple(np.ascontiguousarray(dirs[:, i]) for i in range(3))

    def __len__(self) -> int:
        return self.dirs.shape[0]

    @functools.cache  # noqa: B019 - a bundle lives for one ray cast
    def rotated(self, yaw: float) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...]]:
        """Columns and inverse columns of the directions in a frame yawed by ``yaw`` (rad)."""
        x, y, z = self.cols
        if yaw:
            c, s = np.cos(yaw), np.sin(yaw)
            x, y = c * x + s * y, -s * x + c * y
        cols = (x, y, z)
        inv = tuple(1.0 / np.where(np.abs(v) < 1e-12, 1e-12, v) for v in cols)
        return cols, inv


def _slabs(o: np.ndarray, lo: np.ndarray, hi: np.ndarray, inv: tuple[np.ndarray, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Entry and exit parameters of an axis-aligned box [lo, hi] for rays from point ``o``."""
    t_near = t_far = None
    for axis in range(3):
        t0 = (lo[axis] - o[axis]) * inv[axis]
        t1 = (hi[axis] - o[axis]) * inv[axis]
        near, far = np.minimum(t0, t1), np.maximum(t0, t1)
        t_near = near if t_near is None else np.maximum(t_near, near)
        t_far = far if t_far is None else np.minimum(t_far, far)
    return t_near, t_far  # type: ignore[return-value]


@dataclass(frozen=True)
class Primitive(abc.ABC):
    """Common fields: the class id and the surface material."""

    label: int
    material: Material

    @abc.abstractmethod
    def intersect(self, origin: np.ndarray, rays: Rays) -> np.ndarray:  # [R]
        """Nearest positive hit distance along each ray (inf on a miss)."""

    @abc.abstractmethod
    def normal(self, points: np.ndarray) -> np.ndarray:  # [R, 3]
        """Unit surface normals at hit points."""

    def labels_at(self, points: np.ndarray) -> np.ndarray:  # [R] int
        """Class id at hit points (constant unless a subclass says otherwise)."""
        return np.full(points.shape[0], self.label, dtype=np.int32)

    def colors_at(self, points: np.ndarray, normals: np.ndarray, seed: int) -> np.ndarray:  # [R, 3]
        """Shaded colour at hit points."""
        return shade(self.material, points, normals, seed)


@dataclass(frozen=True)
class Box(Primitive):
    """A box with centre, half extents and a yaw (rad) about the world z axis."""

    center: tuple[float, float, float] = (0.0, 0.0, 0.0)
    half: tuple[float, float, float] = (0.5, 0.5, 0.5)
    yaw: float = 0.0

    def _to_local(self, v: np.ndarray) -> np.ndarray:
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        return np.stack([c * v[..., 0] + s * v[..., 1], -s * v[..., 0] + c * v[..., 1], v[..., 2]], axis=-1)

    def intersect(self, origin: np.ndarray, rays: Rays) -> np.ndarray:
        """Slab test in the box frame."""
        o = self._to_local(origin - np.asarray(self.center))
        _, inv = rays.rotated(self.yaw)
        half = np.asarray(self.half)
        t_near, t_far = _slabs(o, -half, half, inv)
        t = np.where(t_near > _EPS, t_near, t_far)
        return np.where((t_far >= t_near) & (t_far > _EPS), t, np.inf)

    def normal(self, points: np.ndarray) -> np.ndarray:
        """Normal of the face whose slab the point lies on."""
        p = self._to_local(points - np.asarray(self.center)) / np.asarray(self.half)
        axis = np.abs(p).argmax(axis=1)
        n_local = np.zeros_like(p)
        n_local[np.arange(len(p)), axis] = np.sign(p[np.arange(len(p)), axis])
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        return np.stack(
            [c * n_local[:, 0] - s * n_local[:, 1], s * n_local[:, 0] + c * n_local[:, 1], n_local[:, 2]], 1
        )


@dataclass(frozen=True)
class Sphere(Primitive):
    """A sphere."""

    center: tuple[float, float, float] = (0.0, 0.0, 0.0)
    radius: float = 0.5

    def intersect(self, origin: np.ndarray, rays: Rays) -> np.ndarray:
        """Quadratic solution, nearest positive root."""
        oc = origin - np.asarray(self.center)
        x, y, z = rays.cols
        a = x * x + y * y + z * z
        b = 2 * (oc[0] * x + oc[1] * y + oc[2] * z)
        c = float(oc @ oc) - self.radius**2
        disc = b * b - 4 * a * c
        sq = np.sqrt(np.maximum(disc, 0))
        t0, t1 = (-b - sq) / (2 * a), (-b + sq) / (2 * a)
        t = np.where(t0 > _EPS, t0, t1)
        return np.where((disc >= 0) & (t > _EPS), t, np.inf)

    def normal(self, points: np.ndarray) -> np.ndarray:
        """Radial direction."""
        n = points - np.asarray(self.center)
        return n / np.linalg.norm(n, axis=1, keepdims=True)


@dataclass(frozen=True)
class Cylinder(Primitive):
    """A capped cylinder with a vertical axis through (cx, cy), from z0 to z1."""

    center_xy: tuple[float, float] = (0.0, 0.0)
    radius: float = 0.2
    z0: float = 0.0
    z1: float = 1.0

    def intersect(self, origin: np.ndarray, rays: Rays) -> np.ndarray:
        """Side (quadratic in xy, clipped to z) and the two caps."""
        ox, oy, oz = origin[0] - self.center_xy[0], origin[1] - self.center_xy[1], origin[2]
        dx, dy, dz = rays.cols
        a = dx * dx + dy * dy
        b = 2 * (ox * dx + oy * dy)
        c = ox * ox + oy * oy - self.radius**2
        disc = b * b - 4 * a * c
        sq = np.sqrt(np.maximum(disc, 0))
        a_safe = np.where(a < 1e-12, 1.0, a)
        best = np.full(len(rays), np.inf)
        for root in ((-b - sq) / (2 * a_safe), (-b + sq) / (2 * a_safe)):
            z = oz + root * dz
            ok = (disc >= 0) & (a > 1e-12) & (root > _EPS) & (z >= self.z0) & (z <= self.z1)
            best = np.where(ok & (root < best), root, best)
        inv_z = rays.rotated(0.0)[1][2]
        for zc in (self.z0, self.z1):
            root = (zc - oz) * inv_z
            px, py = ox + root * dx, oy + root * dy
            ok = (root > _EPS) & (px * px + py * py <= self.radius**2)
            best = np.where(ok & (root < best), root, best)
        return best

    def normal(self, points: np.ndarray) -> np.ndarray:
        """Radial on the side, +-z on the caps."""
        rx, ry = points[:, 0] - self.center_xy[0], points[:, 1] - self.center_xy[1]
        on_cap = np.minimum(np.abs(points[:, 2] - self.z0), np.abs(points[:, 2] - self.z1)) < 1e-4
        side = np.stack([rx, ry, np.zeros_like(rx)], 1) / self.radius
        cap = np.zeros_like(points)
        cap[:, 2] = np.where(np.abs(points[:, 2] - self.z1) < 1e-4, 1.0, -1.0)
        return np.where(on_cap[:, None], cap, side)


@dataclass(frozen=True)
class RoomShell(Primitive):
    """The inside of an axis-aligned room: floor (z = z0), ceiling (z = z1) and four walls."""

    lo: tuple[float, float, float] = (-3.0, -2.5, 0.0)
    hi: tuple[float, float, float] = (3.0, 2.5, 2.8)
    floor: tuple[int, Material] | None = None
    ceiling: tuple[int, Material] | None = None

    def intersect(self, origin: np.ndarray, rays: Rays) -> np.ndarray:
        """Exit distance of the box (rays start inside)."""
        _, t = _slabs(origin, np.asarray(self.lo), np.asarray(self.hi), rays.rotated(0.0)[1])
        return np.where(t > _EPS, t, np.inf)

    def normal(self, points: np.ndarray) -> np.ndarray:
        """Inward normal of the nearest face."""
        dist = np.concatenate([points - np.asarray(self.lo), np.asarray(self.hi) - points], 1)  # [R, 6]
        face = dist.argmin(axis=1)
        n = np.zeros_like(points)
        n[np.arange(len(points)), face % 3] = np.where(face < 3, 1.0, -1.0)
        return n

    def face_part(self, points: np.ndarray) -> np.ndarray:  # [R] 0 wall, 1 floor, 2 ceiling
        """Which part of the shell each point is on."""
        near_floor = np.abs(points[:, 2] - self.lo[2]) < 1e-4
        near_ceiling = np.abs(points[:, 2] - self.hi[2]) < 1e-4
        return np.where(near_floor, 1, np.where(near_ceiling, 2, 0))

    def colors_at(self, points: np.ndarray, normals: np.ndarray, seed: int) -> np.ndarray:
        """Each part shaded with its own material."""
        out = shade(self.material, points, normals, seed)
        part = self.face_part(points)
        for index, spec in ((1, self.floor), (2, self.ceiling)):
            mask = part == index
            if spec is not None and mask.any():
                out[mask] = shade(spec[1], points[mask], normals[mask], seed + index)
        return out

    def labels_at(self, points: np.ndarray) -> np.ndarray:
        """Wall, floor or ceiling id."""
        part = self.face_part(points)
        ids = np.full(points.shape[0], self.label, dtype=np.int32)
        if self.floor is not None:
            ids[part == 1] = self.floor[0]
        if self.ceiling is not None:
            ids[part == 2] = self.ceiling[0]
        return ids
