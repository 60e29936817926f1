"""Label tables: class id -> name -> colour.

Label images hold class ids (0 = unlabelled); colours are only a rendering of them. Ids missing from
a table get a deterministic colour from the PASCAL VOC bit-interleaving palette, so the same id has
the same colour in every run, node and file.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import numpy as np

from sgs_slam_core.errors import SgsSlamError

__all__ = ["LabelClass", "LabelError", "LabelTable", "palette_color"]

UNLABELLED = 0
MAX_CLASS_ID = 2**31 - 1  # label images hold int32 ids


class LabelError(SgsSlamError, KeyError):
    """An unknown class name or an invalid class id."""

    def __str__(self) -> str:  # KeyError quotes its message; keep it readable
        return str(self.args[0]) if self.args else ""


@dataclass(frozen=True)
class LabelClass:
    """One semantic class."""

    id: int
    name: str
    color: tuple[int, int, int]  # RGB, 0..255


def palette_color(class_id: int) -> tuple[int, int, int]:
    """Deterministic colour of an id (VOC bit-interleaving palette); id 0 is black."""
    if not 0 <= class_id <= MAX_CLASS_ID:
        raise LabelError(f"class ids are in 0..{MAX_CLASS_ID}, got {class_id}")
    r = g = b = 0
    c = class_id
    for shift in range(7, -1, -1):
        r |= ((c >> 0) & 1) << shift
        g |= ((c >> 1) & 1) << shift
        b |= ((c >> 2) & 1) << shift
        c >>= 3
        if c == 0:
            break
    return (r, g, b)


# NYU40 classes with the ScanNet benchmark colours (id 0 = unlabelled, black).
_NYU40 = (
    ("wall", (174, 199, 232)), ("floor", (152, 223, 138)), ("cabinet", (31, 119, 180)),
    ("bed", (255, 187, 120)), ("chair", (188, 189, 34)), ("sofa", (140, 86, 75)),
    ("table", (255, 152, 150)), ("door", (214, 39, 40)), ("window", (197, 176, 213)),
    ("bookshelf", (148, 103, 189)), ("picture", (196, 156, 148)), ("counter", (23, 190, 207)),
    ("blinds", (178, 76, 76)), ("desk", (247, 182, 210)), ("shelves", (66, 188, 102)),
    ("curtain", (219, 219, 141)), ("dresser", (140, 57, 197)), ("pillow", (202, 185, 52)),
    ("mirror", (51, 176, 203)), ("floor mat", (200, 54, 131)), ("clothes", (92, 193, 61)),
    ("ceiling", (78, 71, 183)), ("books", (172, 114, 82)), ("refrigerator", (255, 127, 14)),
    ("television", (91, 163, 138)), ("paper", (153, 98, 156)), ("towel", (140, 153, 101)),
    ("shower curtain", (158, 218, 229)), ("box", (100, 125, 154)), ("whiteboard", (178, 127, 135)),
    ("person", (120, 185, 128)), ("night stand", (146, 111, 194)), ("toilet", (44, 160, 44)),
    ("sink", (112, 128, 144)), ("lamp", (96, 207, 209)), ("bathtub", (227, 119, 194)),
    ("bag", (213, 92, 176)), ("otherstructure", (94, 106, 211)), ("otherfurniture", (82, 84, 163)),
    ("otherprop", (100, 85, 144)),
)  # fmt: skip


class LabelTable:
    """An immutable mapping of class ids to names and colours."""

    def __init__(self, classes: Iterable[LabelClass] = (), name: str = "") -> None:
        self.name = name
        by_id: dict[int, LabelClass] = {UNLABELLED: LabelClass(UNLABELLED, "unlabelled", (0, 0, 0))}
        for cls in classes:
            if not 0 <= cls.id <= MAX_CLASS_ID:
                raise LabelError(f"class ids are in 0..{MAX_CLASS_ID}, got {cls.id} ({cls.name!r})")
            if len(cls.color) != 3 or not all(0 <= v <= 255 for v in cls.color):
                raise LabelError(f"colour of class {cls.id} must be 3 values in 0..255, got {cls.color}")
            by_id[cls.id] = LabelClass(int(cls.id), str(cls.name), tuple(int(v) for v in cls.color))  # type: ignore[arg-type]
        self._by_id = dict(sorted(by_id.items()))
        self._by_name = {c.name: c for c in self._by_id.values()}

    # ------------------------------------------------------------------ factories
    @classmethod
    def nyu40(cls) -> LabelTable:
        """The 40 NYU classes used by ScanNet, with the benchmark's colours."""
        return cls((LabelClass(i + 1, n, c) for i, (n, c) in enumerate(_NYU40)), name="nyu40")

    @classmethod
    def from_ids(cls, ids: Iterable[int], name: str = "") -> LabelTable:
        """Classes ``class_<id>`` with palette colours, for datasets that ship only ids."""
        return cls((LabelClass(int(i), f"class_{int(i)}", palette_color(int(i))) for i in ids if int(i) != 0), name)

    @classmethod
    def from_dict(cls, data: Mapping[str, object]) -> LabelTable:
        """Inverse of :meth:`to_dict`; anything else raises :class:`LabelError` naming the entry."""
        if not isinstance(data, Mapping) or not isinstance(data.get("classes"), list):
            raise LabelError("malformed label table: expected a mapping with a list 'classes'")
        classes = []
        for n, c in enumerate(data["classes"]):
            try:
                if not isinstance(c, Mapping) or isinstance(c["id"], bool) or not isinstance(c["color"], list | tuple):
                    raise TypeError("expected {id, name, color: [r, g, b]}")
                if isinstance(c["id"], float) and not c["id"].is_integer():
                    raise TypeError(f"id {c['id']} is not an integer")
                classes.append(LabelClass(int(c["id"]), str(c["name"]), tuple(int(v) for v in c["color"])))  # type: ignore[arg-type]
            except (KeyError, TypeError, ValueError, OverflowError) as err:
                raise LabelError(f"malformed label table: class {n}: {type(err).__name__} {err}") from err
        return cls(classes, name=str(data.get("name", "")))

    def to_dict(self) -> dict[str, object]:
        """Plain data (for YAML/JSON): ``{"name": ..., "classes": [{"id", "name", "color"}]}``."""
        return {
            "name": self.name,
            "classes": [{"id": c.id, "name": c.name, "color": list(c.color)} for c in self._by_id.values()],
        }

    def with_ids(self, ids: Iterable[int]) -> LabelTable:
        """This table plus palette entries for ids it does not know."""
        extra = [LabelClass(int(i), f"class_{int(i)}", palette_color(int(i))) for i in ids if int(i) not in self]
        return LabelTable([*self._by_id.values(), *extra], self.name) if extra else self

    # ------------------------------------------------------------------ queries
    def __contains__(self, class_id: object) -> bool:
        return class_id in self._by_id

    def __len__(self) -> int:
        return len(self._by_id)

    def __iter__(self):
        return iter(self._by_id.values())

    def __eq__(self, other: object) -> bool:
        return isinstance(other, LabelTable) and self._by_id == other._by_id

    def __hash__(self) -> int:
        return hash(tuple(self._by_id.values()))

    @property
    def ids(self) -> list[int]:
        """Known ids in increasing order (0 included)."""
        return list(self._by_id)

    def name_of(self, class_id: int) -> str:
        """Name of an id (``class_<id>`` when unknown)."""
        cls = self._by_id.get(int(class_id))
        return cls.name if cls else f"class_{int(class_id)}"

    def color_of(self, class_id: int) -> tuple[int, int, int]:
        """Colour of an id (palette colour when unknown)."""
        cls = self._by_id.get(int(class_id))
        return cls.color if cls else palette_color(int(class_id))

    def id_of(self, name_or_id: str | int) -> int:
        """Id of a class given by name (or an id as a string or int)."""
        if isinstance(name_or_id, int) or str(name_or_id).isdigit():
            return int(name_or_id)
        cls = self._by_name.get(str(name_or_id))
        if cls is None:
            raise LabelError(f"unknown class name {name_or_id!r}; known: {', '.join(sorted(self._by_name))}")
        return cls.id

    def lookup_table(self, max_id: int) -> np.ndarray:  # [max_id + 1, 3] uint8
        """Colours of ids 0..max_id, for vectorised colouring."""
        return np.array([self.color_of(i) for i in range(max_id + 1)], dtype=np.uint8)

    def colorize(self, labels: np.ndarray) -> np.ndarray:  # [...] int -> [..., 3] uint8
        """Colour image of a label image."""
        labels = np.asarray(labels)
        if labels.size == 0:
            return np.zeros((*labels.shape, 3), np.uint8)
        if labels.min() < 0:
            raise LabelError(f"label ids must be non-negative, got {labels.min()}")
        uniq, inverse = np.unique(labels, return_inverse=True)
        colors = np.array([self.color_of(int(i)) for i in uniq], dtype=np.uint8)
        return colors[inverse.reshape(labels.shape)]
