"""ADE20K's 150 scene-parsing classes and their NYU40 equivalents.

Models trained on ADE20K (SceneParse150, e.g. SegFormer) predict these 150 classes in this order;
the SLAM's default label table is NYU40 (ScanNet's benchmark classes), so a live camera and a
ScanNet replay speak one vocabulary. The mapping goes by meaning: a class with an NYU40 namesake
maps to it (``armchair`` and ``swivel chair`` to ``chair``, ``painting`` and ``poster`` to
``picture``), other indoor furniture, structure and objects to ``otherfurniture``,
``otherstructure`` and ``otherprop``, and outdoor classes (sky, road, car, ...) to 0, unlabelled,
which the SLAM does not learn from.
"""

from __future__ import annotations

import numpy as np

from sgs_slam_core.labels import LabelTable

__all__ = ["ADE20K_CLASSES", "ADE20K_TO_NYU40", "ade20k_to_nyu40_lut"]

# SceneParse150 order (class index 0..149), names as in the ADE20K benchmark's objectInfo150
ADE20K_CLASSES = (
    "wall", "building", "sky", "floor", "tree", "ceiling", "road", "bed", "windowpane", "grass",
    "cabinet", "sidewalk", "person", "earth", "door", "table", "mountain", "plant", "curtain", "chair",
    "car", "water", "painting", "sofa", "shelf", "house", "sea", "mirror", "rug", "field",
    "armchair", "seat", "fence", "desk", "rock", "wardrobe", "lamp", "bathtub", "railing", "cushion",
    "base", "box", "column", "signboard", "chest of drawers", "counter", "sand", "sink", "skyscraper",
    "fireplace", "refrigerator", "grandstand", "path", "stairs", "runway", "case", "pool table", "pillow",
    "screen door", "stairway", "river", "bridge", "bookcase", "blind", "coffee table", "toilet", "flower",
    "book", "hill", "bench", "countertop", "stove", "palm", "kitchen island", "computer", "swivel chair",
    "boat", "bar", "arcade machine", "hovel", "bus", "towel", "light", "truck", "tower", "chandelier",
    "awning", "streetlight", "booth", "television receiver", "airplane", "dirt track", "apparel", "pole",
    "land", "bannister", "escalator", "ottoman", "bottle", "buffet", "poster", "stage", "van", "ship",
    "fountain", "conveyer belt", "canopy", "washer", "plaything", "swimming pool", "stool", "barrel",
    "basket", "waterfall", "tent", "bag", "minibike", "cradle", "oven", "ball", "food", "step", "tank",
    "trade name", "microwave", "pot", "animal", "bicycle", "lake", "dishwasher", "screen", "blanket",
    "sculpture", "hood", "sconce", "vase", "traffic light", "tray", "ashcan", "fan", "pier", "crt screen",
    "plate", "monitor", "bulletin board", "shower", "radiator", "glass", "clock", "flag",
)  # fmt: skip

_OTHERSTRUCTURE = ("building", "house", "fence", "railing", "base", "column", "fireplace", "stairs",
                   "stairway", "bannister", "escalator", "stage", "canopy", "pole", "step", "shower", "skyscraper",
                   "tower")  # fmt: skip
_OTHERFURNITURE = ("wardrobe", "case", "bench", "stove", "bar", "arcade machine", "ottoman", "buffet", "washer",
                   "stool", "cradle", "oven", "dishwasher", "radiator")  # fmt: skip
_OTHERPROP = ("plant", "signboard", "flower", "computer", "bottle", "conveyer belt", "plaything", "barrel", "basket",
              "ball", "food", "tank", "trade name", "microwave", "pot", "blanket", "sculpture", "hood", "vase", "tray",
              "ashcan", "fan", "plate", "glass", "clock", "flag", "fountain")  # fmt: skip
_NAMESAKES = {
    "wall": "wall", "floor": "floor", "ceiling": "ceiling", "bed": "bed", "windowpane": "window",
    "cabinet": "cabinet", "person": "person", "door": "door", "screen door": "door", "table": "table",
    "coffee table": "table", "pool table": "table", "curtain": "curtain", "chair": "chair", "armchair": "chair",
    "swivel chair": "chair", "seat": "chair", "painting": "picture", "poster": "picture", "sofa": "sofa",
    "shelf": "shelves", "bookcase": "bookshelf", "mirror": "mirror", "rug": "floor mat", "desk": "desk",
    "lamp": "lamp", "light": "lamp", "chandelier": "lamp", "sconce": "lamp", "bathtub": "bathtub",
    "cushion": "pillow", "pillow": "pillow", "box": "box", "chest of drawers": "dresser", "counter": "counter",
    "countertop": "counter", "kitchen island": "counter", "sink": "sink", "refrigerator": "refrigerator",
    "blind": "blinds", "toilet": "toilet", "book": "books", "towel": "towel", "television receiver": "television",
    "screen": "television", "crt screen": "television", "monitor": "television", "apparel": "clothes",
    "bag": "bag", "bulletin board": "whiteboard",
}  # fmt: skip

ADE20K_TO_NYU40: dict[str, str] = {
    **dict.fromkeys(_OTHERSTRUCTURE, "otherstructure"),
    **dict.fromkeys(_OTHERFURNITURE, "otherfurniture"),
    **dict.fromkeys(_OTHERPROP, "otherprop"),
    **_NAMESAKES,
}  # ADE20K classes not listed (outdoor scenes) are unlabelled


def ade20k_to_nyu40_lut(table: LabelTable | None = None) -> np.ndarray:  # [150] int64
    """NYU40 id of every ADE20K class index (0 = unlabelled), by name in ``table`` (default NYU40)."""
    table = table or LabelTable.nyu40()
    return np.array([table.id_of(ADE20K_TO_NYU40[n]) if n in ADE20K_TO_NYU40 else 0 for n in ADE20K_CLASSES])
