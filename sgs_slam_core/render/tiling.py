"""Binning of projected Gaussians into image tiles (integer work only, no autograd).

The plan lists, for every non-empty tile, its Gaussians in front-to-back order. Tiles are sorted by
their Gaussian count and grouped into chunks with a common padded length, so the compositor works
on dense ``[tiles, pixels, slots]`` blocks with little padding and bounded memory.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

__all__ = ["TileChunk", "TilePlan", "plan_tiles"]


@dataclass
class TileChunk:
    """A batch of tiles with the same padded list length K."""

    tiles: Tensor  # [Tc] tile ids (row-major over the tile grid)
    gauss: Tensor  # [Tc, K] Gaussian ids, front to back; the pad id N marks empty slots
    x0: Tensor  # [Tc] x of the tile's first pixel column
    y0: Tensor  # [Tc] y of the tile's first pixel row
    px: Tensor  # [Tc, P] pixel-centre x of each tile pixel (P = tile_size^2, row-major in the tile)
    py: Tensor  # [Tc, P] pixel-centre y


@dataclass
class TilePlan:
    """Everything the compositor needs besides the per-Gaussian tensors."""

    width: int
    height: int
    tile_size: int
    tiles_x: int
    tiles_y: int
    num_gaussians: int  # N; slot id N is the transparent pad Gaussian
    num_intersections: int
    chunks: list[TileChunk]

    @property
    def num_tiles(self) -> int:
        """Tiles in the grid, empty ones included."""
        return self.tiles_x * self.tiles_y

    @property
    def evaluated_pairs(self) -> int:
        """Pixel x slot pairs the compositor evaluates (padding included)."""
        return sum(c.gauss.numel() * c.px.shape[1] for c in self.chunks)


@torch.no_grad()
def plan_tiles(
    means2d: Tensor,  # [N, 2]
    radii: Tensor,  # [N] pixels, 0 = culled
    depths: Tensor,  # [N]
    width: int,
    height: int,
    tile_size: int,
    chunk_elements: int,
    dtype: torch.dtype | None = None,
) -> TilePlan:
    """Assign Gaussians to the tiles their footprint box touches and sort each tile by depth."""
    device = means2d.device
    n = means2d.shape[0]
    ts = tile_size
    tiles_x, tiles_y = math.ceil(width / ts), math.ceil(height / ts)
    u, v = means2d[:, 0].detach(), means2d[:, 1].detach()
    r = radii.detach()
    # Pixel ranges [lo, hi] whose centres lie within the radius, clipped to the image.
    x_lo, x_hi = torch.ceil(u - r), torch.floor(u + r)
    y_lo, y_hi = torch.ceil(v - r), torch.floor(v + r)
    hit = (r > 0) & (x_lo <= width - 1) & (x_hi >= 0) & (y_lo <= height - 1) & (y_hi >= 0) & (x_lo <= x_hi)
    hit &= (y_lo <= y_hi) & torch.isfinite(u) & torch.isfinite(v)
    ids = torch.nonzero(hit).squeeze(1)
    tx0 = (x_lo[ids].clamp(0, width - 1).long()) // ts
    tx1 = (x_hi[ids].clamp(0, width - 1).long()) // ts
    ty0 = (y_lo[ids].clamp(0, height - 1).long()) // ts
    ty1 = (y_hi[ids].clamp(0, height - 1).long()) // ts
    nx, ny = tx1 - tx0 + 1, ty1 - ty0 + 1
    counts = nx * ny
    total = int(counts.sum())
    pad_dtype = dtype or means2d.dtype
    if total == 0:
        return TilePlan(width, height, ts, tiles_x, tiles_y, n, 0, [])

    gid = torch.repeat_interleave(ids, counts)
    starts = torch.cumsum(counts, 0) - counts
    local = torch.arange(total, device=device) - torch.repeat_interleave(starts, counts)
    nx_rep = torch.repeat_interleave(nx, counts)
    tile = (torch.repeat_interleave(ty0, counts) + local // nx_rep) * tiles_x
    tile += torch.repeat_interleave(tx0, counts) + local % nx_rep

    rank = torch.empty(n, dtype=torch.long, device=device)
    order = torch.argsort(depths.detach()[ids], stable=True)
    rank[ids[order]] = torch.arange(ids.numel(), device=device)
    key = tile * (n + 1) + rank[gid]
    perm = torch.sort(key).indices
    gid_sorted = gid[perm]
    tile_counts = torch.bincount(tile, minlength=tiles_x * tiles_y)
    tile_starts = torch.cumsum(tile_counts, 0) - tile_counts

    return TilePlan(
        width=width,
        height=height,
        tile_size=ts,
        tiles_x=tiles_x,
        tiles_y=tiles_y,
        num_gaussians=n,
        num_intersections=total,
        chunks=_make_chunks(gid_sorted, tile_counts, tile_starts, tiles_x, ts, n, chunk_elements, pad_dtype),
    )


def _make_chunks(
    gid_sorted: Tensor,  # [I]
    tile_counts: Tensor,  # [T]
    tile_starts: Tensor,  # [T]
    tiles_x: int,
    ts: int,
    n: int,
    chunk_elements: int,
    dtype: torch.dtype,
) -> list[TileChunk]:
    device = gid_sorted.device
    nonempty = torch.nonzero(tile_counts).squeeze(1)
    order = torch.argsort(tile_counts[nonempty], descending=True, stable=True)
    tiles_sorted = nonempty[order]
    counts_sorted = tile_counts[tiles_sorted].tolist()
    pixels = ts * ts
    local = torch.arange(pixels, device=device)
    lx, ly = (local % ts).to(dtype), (local // ts).to(dtype)

    chunks: list[TileChunk] = []
    begin = 0
    while begin < len(counts_sorted):
        k = counts_sorted[begin]
        per_tile = k * pixels
        take = max(1, min(len(counts_sorted) - begin, chunk_elements // per_tile))
        tiles = tiles_sorted[begin : begin + take]
        slot = torch.arange(k, device=device)
        pos = tile_starts[tiles][:, None] + slot[None, :]
        valid = slot[None, :] < tile_counts[tiles][:, None]
        gauss = torch.where(valid, gid_sorted[pos.clamp_max(gid_sorted.numel() - 1)], torch.full_like(pos, n))
        x0 = ((tiles % tiles_x) * ts).to(dtype)
        y0 = ((tiles // tiles_x) * ts).to(dtype)
        chunks.append(TileChunk(tiles=tiles, gauss=gauss, x0=x0, y0=y0, px=x0[:, None] + lx, py=y0[:, None] + ly))
        begin += take
    return chunks
