"""Label sources for live cameras: a pretrained segmentation model and its classes mapped to NYU40."""

from sgs_slam_core.segmentation.ade20k import ADE20K_CLASSES, ADE20K_TO_NYU40, ade20k_to_nyu40_lut
from sgs_slam_core.segmentation.segformer import DEFAULT_MODEL, SegmentationError, Segmenter

__all__ = [
    "ADE20K_CLASSES",
    "ADE20K_TO_NYU40",
    "DEFAULT_MODEL",
    "SegmentationError",
    "Segmenter",
    "ade20k_to_nyu40_lut",
]
