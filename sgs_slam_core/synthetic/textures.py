"""Procedural, view-independent surface appearance (deterministic by seed)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

__all__ = ["Material", "shade", "value_noise"]

Pattern = Literal["noise", "stripes", "checker", "grain"]
LIGHT_DIR = np.array([0.35, -0.45, 0.82]) / np.linalg.norm([0.35, -0.45, 0.82])


@dataclass(frozen=True)
class Material:
    """Albedo = base * (1 + amplitude * pattern(p / scale)), then Lambertian shading."""

    base: tuple[float, float, float]  # linear RGB in [0, 1]
    pattern: Pattern = "noise"
    scale: float = 0.25  # metres per pattern period
    amplitude: float = 0.35
    tint: tuple[float, float, float] = (0.0, 0.0, 0.0)  # extra colour variation along the pattern


def _hash(ix: np.ndarray, iy: np.ndarray, iz: np.ndarray, seed: int) -> np.ndarray:
    h = ix * 73856093 ^ iy * 19349663 ^ iz * 83492791 ^ (seed * 2654435761 & 0xFFFFFFFF)
    h = (h ^ (h >> 13)) * 1274126177
    return ((h ^ (h >> 16)) & 0xFFFF).astype(np.float64) / 0xFFFF


def value_noise(p: np.ndarray, seed: int) -> np.ndarray:  # [R, 3] -> [R] in [-1, 1]
    """Trilinearly interpolated lattice noise with a smoothstep fade (C1-continuous)."""
    base = np.floor(p)
    f = p - base
    f = f * f * (3 - 2 * f)
    i = base.astype(np.int64)
    out = np.zeros(p.shape[0])
    for dx in (0, 1):
        wx = f[:, 0] if dx else 1 - f[:, 0]
        for dy in (0, 1):
            wy = f[:, 1] if dy else 1 - f[:, 1]
            for dz in (0, 1):
                wz = f[:, 2] if dz else 1 - f[:, 2]
                out += wx * wy * wz * _hash(i[:, 0] + dx, i[:, 1] + dy, i[:, 2] + dz, seed)
    return 2 * out - 1


def _pattern(material: Material, p: np.ndarray, seed: int) -> np.ndarray:  # [R] in ~[-1, 1]
    q = p / material.scale
    if material.pattern == "stripes":
        return np.sin(2 * np.pi * (q[:, 0] + 0.5 * q[:, 1] + 0.25 * q[:, 2])) * 0.7 + 0.3 * value_noise(q, seed)
    if material.pattern == "checker":
        soft = np.sin(np.pi * q[:, 0]) * np.sin(np.pi * q[:, 1]) * np.sin(np.pi * q[:, 2] + 0.5)
        return np.tanh(4 * soft) * 0.8 + 0.2 * value_noise(4 * q, seed)
    if material.pattern == "grain":
        warp = value_noise(q * np.array([0.5, 0.5, 4.0]), seed)
        return np.sin(2 * np.pi * (q[:, 0] * 3 + 2 * warp))
    return 0.65 * value_noise(q, seed) + 0.35 * value_noise(3.1 * q, seed + 1)


def shade(material: Material, points: np.ndarray, normals: np.ndarray, seed: int) -> np.ndarray:  # [R, 3]
    """Shaded linear RGB in [0, 1] at surface points (view-independent)."""
    pat = _pattern(material, points, seed)[:, None]
    albedo = np.asarray(material.base) * (1 + material.amplitude * pat) + np.asarray(material.tint) * pat
    lambert = np.abs(normals @ LIGHT_DIR)[:, None]  # two-sided, so inner room faces are lit too
    return np.clip(albedo * (0.45 + 0.55 * lambert), 0.0, 1.0)
