"""Coordinate frame names shared by bags, viewers and nodes (a RealSense driver's names)."""

__all__ = ["CAMERA_FRAME", "MAP_FRAME"]

CAMERA_FRAME = "camera_color_optical_frame"  # the colour camera's optical frame: x right, y down, z forward
MAP_FRAME = "map"
