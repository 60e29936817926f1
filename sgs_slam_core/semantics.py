"""Semantic channel encodings: label images <-> per-pixel semantic features.

Two modes:

* ``color`` - paper-faithful: S = 3, the target is the class's palette colour in [0, 1]; decoding
  snaps a rendered colour to the nearest class colour.
* ``onehot`` - S = K: channel k is the probability of class id k; decoding is an argmax.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import torch
from torch import Tensor

from sgs_slam_core.errors import ConfigError, FrameError, ShapeError
from sgs_slam_core.labels import LabelTable

__all__ = ["BLEND_FRACTION", "SemanticCodec", "SemanticFusion", "SemanticMode", "SemanticSettings"]

SemanticMode = Literal["color", "onehot"]
SemanticFusion = Literal["regression", "votes"]
_DECODE_ELEMENTS = 1 << 24  # float32 distances per decoding chunk, whatever the number of classes
_PALETTE_IDS = 1 << 16  # ids below this encode by a lookup in a cached palette (uint16 labels all do)


@dataclass(frozen=True)
class SemanticSettings:
    """The ``semantic`` config section.

    Attributes:
        mode: ``color`` (S = 3) or ``onehot`` (S = num_classes).
        num_classes: one-hot channels, covering class ids 0 .. num_classes - 1 (ignored in colour mode).
        fusion: how the label images make a Gaussian's class. ``regression`` (the paper): its semantic
            features are optimised with the map against each window's labels, the class decoded from
            them. ``votes``: each labelled view votes the class its centre falls on, the majority
            is the class, and the features are that class's target (the segmenter's flicker in a
            few views does not move it).
    """

    mode: SemanticMode = "color"
    num_classes: int = 41
    fusion: SemanticFusion = "regression"

    def __post_init__(self) -> None:
        if self.mode not in ("color", "onehot"):
            raise ConfigError(f"semantic.mode must be color or onehot, got {self.mode!r}")
        if self.fusion not in ("regression", "votes"):
            raise ConfigError(f"semantic.fusion must be regression or votes, got {self.fusion!r}")
        if self.mode == "onehot" and not 2 <= self.num_classes <= 512:
            raise ConfigError(f"semantic.num_classes must be in [2, 512] for onehot, got {self.num_classes}")


class SemanticCodec:
    """Encodes label ids to semantic targets and decodes rendered semantics to ids."""

    def __init__(self, settings: SemanticSettings, table: LabelTable) -> None:
        self.settings = settings
        self.table = table
        self._palettes: dict[torch.device, Tensor] = {}  # device -> [n, 3] colours of ids 0 .. n-1

    @property
    def mode(self) -> SemanticMode:
        """``color`` or ``onehot``."""
        return self.settings.mode

    @property
    def num_channels(self) -> int:
        """S, the semantic channels per Gaussian and pixel."""
        return 3 if self.mode == "color" else self.settings.num_classes

    def with_table(self, table: LabelTable) -> SemanticCodec:
        """The same encoding with another label table (e.g. grown by newly seen ids)."""
        return SemanticCodec(self.settings, table)

    def class_colors(self, ids: Sequence[int], device: torch.device | str = "cpu") -> Tensor:  # [C, 3]
        """Palette colours of ``ids`` in [0, 1]."""
        return torch.tensor([self.table.color_of(i) for i in ids], dtype=torch.float32, device=device) / 255.0

    def encode(
        self, labels: Tensor, value_range: tuple[int, int] | None = None
    ) -> Tensor:  # [...] int64 -> [..., S] float32
        """Semantic targets of a label image.

        ``value_range``: the labels' (least, greatest) id where the caller has them on the host; else
        they are read from the labels' device (one read).
        """
        if labels.dtype not in (torch.int16, torch.int32, torch.int64, torch.uint8):
            raise ShapeError(f"labels must be an integer tensor, got {labels.dtype}")
        labels = labels.long()
        if labels.numel() == 0:
            return labels.new_zeros((*labels.shape, self.num_channels), dtype=torch.float32)
        lo, hi = value_range if value_range is not None else torch.stack(tuple(torch.aminmax(labels))).tolist()
        if self.mode == "onehot":
            k = self.settings.num_classes
            if hi >= k:
                raise FrameError(f"class id {hi} >= semantic.num_classes={k}; raise num_classes")
            return torch.nn.functional.one_hot(labels, k).to(torch.float32)
        if lo < 0 or hi >= _PALETTE_IDS:
            return self.encode_by_unique(labels)
        return self._palette(hi + 1, labels.device)[labels]

    def encode_by_unique(self, labels: Tensor) -> Tensor:  # [...] int64 -> [..., 3] float32
        """Colour-mode ``encode`` through the ids present (a sort): the reference, and the path for any id."""
        ids, inverse = torch.unique(labels, return_inverse=True)
        return self.class_colors(ids.tolist(), labels.device)[inverse]

    def _palette(self, count: int, device: torch.device) -> Tensor:  # [n >= count, 3]
        """The colours of ids 0 .. n-1 on ``device``, built once and grown to the next power of two."""
        palette = self._palettes.get(device)
        if palette is None or palette.shape[0] < count:
            n = min(1 << (count - 1).bit_length(), _PALETTE_IDS)
            palette = self.class_colors(range(n), device)
            self._palettes[device] = palette
        return palette

    def decode(self, semantic: Tensor, candidates: Sequence[int] | None = None) -> Tensor:  # [..., S] -> [...]
        """Class ids: nearest candidate colour (colour mode) or argmax over candidates (one-hot).

        ``candidates`` restricts the answer to these ids (the paper's protocol snaps to the ids present
        in the frame's ground truth); by default every id of the table (colour mode) or every channel.
        """
        if semantic.shape[-1] != self.num_channels:
            raise ShapeError(f"semantic has {semantic.shape[-1]} channels, codec expects {self.num_channels}")
        flat = semantic.detach().reshape(-1, self.num_channels).float()
        if self.mode == "onehot":
            if candidates is None:
                return flat.argmax(dim=1).reshape(semantic.shape[:-1])
            k = self.num_channels  # ids without a channel (>= num_classes) can never be decoded
            kept = sorted({i for i in candidates if 0 <= i < k}) or [0]
            ids = torch.tensor(kept, dtype=torch.long, device=semantic.device)
            return ids[flat[:, ids].argmax(dim=1)].reshape(semantic.shape[:-1])
        ids, palette = self._candidate_palette(candidates, semantic.device)
        index, _ = _nearest_colors(flat, palette)
        return ids[index].reshape(semantic.shape[:-1])

    def decode_image(self, semantic: Tensor, candidates: Sequence[int] | None = None) -> Tensor:  # [H, W, S] -> [H, W]
        """Class ids of a rendered image: :meth:`decode`, with the blends at class boundaries resolved.

        In colour mode a pixel where two classes' Gaussians overlap renders a mix of their colours, and
        the nearest class colour to that mix is often a third class that is nowhere near (on the
        synthetic room most decoding errors were such pixels). A pixel farther from its nearest colour
        than ``BLEND_FRACTION`` of that colour's distance to the next candidate colour is a blend: it
        takes, of the classes its confidently decoded 8-neighbours have, the one whose colour is nearest.
        One-hot mixtures need no such step (their argmax is one of the mixed classes).
        """
        if semantic.ndim != 3:
            raise ShapeError(f"a semantic image is [H, W, S], got shape {tuple(semantic.shape)}")
        if self.mode == "onehot":
            return self.decode(semantic, candidates)
        if semantic.shape[-1] != 3:
            raise ShapeError(f"semantic has {semantic.shape[-1]} channels, codec expects 3")
        h, w, _ = semantic.shape
        flat = semantic.detach().reshape(-1, 3).float()  # [P, 3]
        ids, palette = self._candidate_palette(candidates, semantic.device)
        index, dist = _nearest_colors(flat, palette)
        blend = dist > BLEND_FRACTION * _next_color_distance(palette)[index]  # [P]
        if bool(blend.any()):
            index = _resolve_blends(flat, palette, index, blend, h, w)
        return ids[index].reshape(h, w)

    def _candidate_palette(self, candidates: Sequence[int] | None, device: torch.device) -> tuple[Tensor, Tensor]:
        """The candidate ids [C] (sorted, unique) and their colours [C, 3] on ``device``."""
        ids_list = sorted(set(self.table.ids if candidates is None else candidates))
        return torch.tensor(ids_list, dtype=torch.long, device=device), self.class_colors(ids_list, device)


# A rendered colour this far from its nearest class colour, as a fraction of that colour's distance to the
# next class colour, is a blend of classes. Chosen on the synthetic room (0.3-0.5 decode alike; 0.1 leaves
# most blends), checked on its noisy labels and on another generated scene (seed 7, a walk, noisy depth).
BLEND_FRACTION = 0.4


def _nearest_colors(flat: Tensor, palette: Tensor) -> tuple[Tensor, Tensor]:  # [P, 3], [C, 3] -> [P], [P]
    """Index of the nearest palette colour of each row, and the distance to it (chunked by memory)."""
    index = torch.empty(flat.shape[0], dtype=torch.long, device=flat.device)
    dist = torch.empty(flat.shape[0], dtype=flat.dtype, device=flat.device)
    step = max(1, _DECODE_ELEMENTS // palette.shape[0])  # the [pixels, classes] distances stay <= 64 MiB
    for begin in range(0, flat.shape[0], step):
        d, i = torch.cdist(flat[begin : begin + step], palette).min(dim=1)
        index[begin : begin + step], dist[begin : begin + step] = i, d
    return index, dist


def _next_color_distance(palette: Tensor) -> Tensor:  # [C, 3] -> [C]
    """Distance from each palette colour to the nearest other one (infinite for a single colour)."""
    d = torch.cdist(palette, palette)
    d.fill_diagonal_(float("inf"))
    return d.min(dim=1).values


def _resolve_blends(
    flat: Tensor,  # [H*W, 3] rendered colours
    palette: Tensor,  # [C, 3]
    index: Tensor,  # [H*W] nearest palette index of each pixel
    blend: Tensor,  # [H*W] bool, the pixels that are blends
    h: int,
    w: int,
) -> Tensor:  # [H*W]
    """Each blend pixel takes the nearest colour among its confident 8-neighbours' classes (if it has any)."""
    confident = index.masked_fill(blend, -1).reshape(h, w)
    padded = torch.nn.functional.pad(confident[None, None], (1, 1, 1, 1), value=-1)[0, 0]  # [H+2, W+2]
    pixels = blend.nonzero()[:, 0]  # [B]
    rows, cols = torch.div(pixels, w, rounding_mode="floor"), pixels % w
    offsets = [(dy, dx) for dy in range(3) for dx in range(3) if (dy, dx) != (1, 1)]
    neighbours = torch.stack([padded[rows + dy, cols + dx] for dy, dx in offsets], dim=1)  # [B, 8]
    known = neighbours >= 0
    d = (flat[pixels, None, :] - palette[neighbours.clamp(min=0)]).square().sum(dim=-1)  # [B, 8]
    best = d.masked_fill(~known, float("inf")).argmin(dim=1)
    resolved = index.clone()
    has = known.any(dim=1)
    resolved[pixels[has]] = neighbours[has, best[has]]
    return resolved
