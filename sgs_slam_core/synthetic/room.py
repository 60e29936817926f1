"""The built-in indoor room: 13 NYU40 classes of furniture in a 6 x 5 x 2.8 m room (world z up)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sgs_slam_core.labels import LabelTable
from sgs_slam_core.synthetic.primitives import Box, Cylinder, Primitive, RoomShell, Sphere
from sgs_slam_core.synthetic.textures import Material

__all__ = ["Scene", "build_room"]

# NYU40 ids used by the room.
WALL, FLOOR, CABINET, BED, CHAIR, SOFA, TABLE, DOOR, WINDOW, BOOKSHELF, PICTURE, CEILING, LAMP = (
    1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 22, 35,
)  # fmt: skip


@dataclass(frozen=True)
class Scene:
    """Primitives plus the label table of the ids they use."""

    primitives: tuple[Primitive, ...]
    label_table: LabelTable
    lo: tuple[float, float, float]
    hi: tuple[float, float, float]

    @property
    def center(self) -> np.ndarray:  # [3]
        """Middle of the room."""
        return (np.asarray(self.lo) + np.asarray(self.hi)) / 2


def _m(rgb: tuple[float, float, float], pattern: str = "noise", scale: float = 0.25, amp: float = 0.35) -> Material:
    return Material(base=rgb, pattern=pattern, scale=scale, amplitude=amp)  # type: ignore[arg-type]


def build_room(seed: int = 0) -> Scene:
    """The room; ``seed`` jitters furniture positions and colours by a few centimetres / percent."""
    rng = np.random.default_rng(seed)

    def jit(v: tuple[float, ...], amount: float = 0.05) -> tuple[float, ...]:
        return tuple(float(x + rng.uniform(-amount, amount)) for x in v)

    def col(rgb: tuple[float, float, float]) -> tuple[float, float, float]:
        return tuple(float(np.clip(c * rng.uniform(0.92, 1.08), 0, 1)) for c in rgb)  # type: ignore[return-value]

    lo, hi = (-3.0, -2.5, 0.0), (3.0, 2.5, 2.8)
    wood = _m(col((0.6, 0.42, 0.25)), "grain", 0.4)
    blue, red, green = col((0.2, 0.35, 0.6)), col((0.65, 0.2, 0.2)), col((0.3, 0.55, 0.35))
    prims: list[Primitive] = [
        RoomShell(
            WALL, _m(col((0.78, 0.74, 0.66)), "noise", 0.6, 0.25), lo=lo, hi=hi,
            floor=(FLOOR, _m(col((0.55, 0.38, 0.24)), "grain", 0.5, 0.3)),
            ceiling=(CEILING, _m(col((0.9, 0.9, 0.88)), "noise", 0.8, 0.1)),
        ),
        # a table with four legs, and two chairs (seat + back)
        Box(TABLE, wood, center=jit((0.3, 0.2, 0.74)), half=(0.7, 0.45, 0.03)),
        *[
            Box(TABLE, _m(col((0.45, 0.3, 0.18))), center=(0.3 + sx * 0.62, 0.2 + sy * 0.38, 0.36),
                half=(0.03, 0.03, 0.36))
            for sx in (-1, 1) for sy in (-1, 1)
        ],
        Box(CHAIR, _m(blue, "checker", 0.1), center=jit((0.3, -0.55, 0.45)), half=(0.22, 0.22, 0.04)),
        Box(CHAIR, _m(blue), center=jit((0.3, -0.75, 0.75)), half=(0.22, 0.03, 0.3)),
        Box(CHAIR, _m(red, "checker", 0.1), center=jit((1.35, 0.2, 0.45)), half=(0.22, 0.22, 0.04), yaw=0.3),
        Box(SOFA, _m(green, "noise", 0.15, 0.4), center=jit((-1.9, 1.9, 0.3)), half=(0.9, 0.4, 0.3)),
        Box(SOFA, _m(green), center=jit((-1.9, 2.2, 0.7)), half=(0.9, 0.1, 0.3)),
        Box(BED, _m(col((0.85, 0.8, 0.9)), "stripes", 0.3, 0.25), center=jit((2.0, -1.6, 0.3)),
            half=(0.8, 0.7, 0.3)),
        Box(CABINET, _m(col((0.5, 0.5, 0.55)), "stripes", 0.12, 0.3), center=jit((-2.65, -1.2, 0.6)),
            half=(0.3, 0.5, 0.6)),
        Box(BOOKSHELF, _m(col((0.4, 0.25, 0.15)), "stripes", 0.08, 0.5), center=jit((2.75, 1.2, 0.9)),
            half=(0.22, 0.6, 0.9)),
        Box(DOOR, _m(col((0.7, 0.55, 0.35)), "grain", 0.3), center=(-0.8, 2.49, 1.0), half=(0.45, 0.02, 1.0)),
        Box(WINDOW, _m(col((0.6, 0.8, 0.95)), "noise", 0.5, 0.15), center=(1.0, -2.49, 1.6),
            half=(0.7, 0.02, 0.5)),
        Box(PICTURE, _m(col((0.9, 0.6, 0.2)), "checker", 0.15, 0.6), center=(-2.99, 0.8, 1.6),
            half=(0.02, 0.4, 0.3)),
        Box(PICTURE, _m(col((0.3, 0.6, 0.8)), "stripes", 0.1, 0.6), center=(2.99, -0.6, 1.7),
            half=(0.02, 0.35, 0.25)),
        Cylinder(LAMP, _m(col((0.75, 0.75, 0.7))), center_xy=(-2.2, -0.3), radius=0.04, z0=0.0, z1=1.4),
        Sphere(LAMP, _m(col((0.95, 0.85, 0.5)), "noise", 0.1, 0.2), center=(-2.2, -0.3, 1.55), radius=0.2),
        Sphere(BED, _m(col((0.9, 0.9, 0.95)), "noise", 0.1, 0.2), center=jit((2.5, -1.6, 0.7)), radius=0.18),
    ]  # fmt: skip
    ids = sorted({p.label for p in prims} | {FLOOR, CEILING})
    nyu = LabelTable.nyu40()
    table = LabelTable((c for c in nyu if c.id in ids), name="synthetic-room")
    return Scene(tuple(prims), table, lo, hi)
