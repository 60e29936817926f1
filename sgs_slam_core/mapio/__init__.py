"""Map files: the native format (resume mapping) and PLY exports/imports."""

from sgs_slam_core.mapio.files import MAP_SUFFIXES, read_any_map, write_any_map
from sgs_slam_core.mapio.native import MapFile, load_map, save_map
from sgs_slam_core.mapio.ply import read_splat_ply, write_map_point_cloud, write_point_cloud_ply, write_splat_ply

__all__ = [
    "MAP_SUFFIXES",
    "MapFile",
    "load_map",
    "read_any_map",
    "read_splat_ply",
    "save_map",
    "write_any_map",
    "write_map_point_cloud",
    "write_point_cloud_ply",
    "write_splat_ply",
]
