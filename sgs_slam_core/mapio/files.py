"""Read and write a map by file name: ``.sgsmap`` (native) or ``.ply`` (3DGS splat layout)."""

from __future__ import annotations

from pathlib import Path

import torch

from sgs_slam_core.errors import MapFileError
from sgs_slam_core.labels import LabelTable
from sgs_slam_core.mapio.native import MapFile, load_map, save_map
from sgs_slam_core.mapio.ply import read_splat_ply, write_splat_ply

__all__ = ["MAP_SUFFIXES", "read_any_map", "write_any_map"]

MAP_SUFFIXES = (".sgsmap", ".ply")


def _suffix(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in MAP_SUFFIXES:
        raise MapFileError(f"{path}: map files end in {' or '.join(MAP_SUFFIXES)}, got {suffix or 'no suffix'!r}")
    return suffix


def read_any_map(path: str | Path, device: torch.device | str = "cpu") -> MapFile:
    """A native map, or a splat PLY wrapped as a map without poses (label table NYU40 if the PLY has none)."""
    path = Path(path)
    if _suffix(path) == ".sgsmap":
        return load_map(path, device)
    if not path.is_file():
        raise MapFileError(f"map file {path} does not exist")
    gaussians, table = read_splat_ply(path)
    return MapFile(gaussians.to(device), table or LabelTable.nyu40())


def write_any_map(path: str | Path, m: MapFile) -> None:
    """Write ``m`` in the format the suffix names (a PLY keeps only the Gaussians and the label table)."""
    path = Path(path)
    if _suffix(path) == ".sgsmap":
        save_map(path, m)
    else:
        write_splat_ply(path, m.gaussians, m.label_table)
