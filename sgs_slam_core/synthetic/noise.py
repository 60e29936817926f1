"""Sensor and labeller imperfections: Kinect-like depth noise, depth holes, label noise."""

from __future__ import annotations

import cv2
import numpy as np

from sgs_slam_core.geometry.depth_noise import DepthNoise

__all__ = ["add_depth_holes", "add_depth_noise", "add_label_noise", "blob_mask"]


def blob_mask(shape: tuple[int, int], fraction: float, rng: np.random.Generator, blob_px: float = 6.0) -> np.ndarray:
    """A boolean mask covering about ``fraction`` of the image in smooth random blobs."""
    if fraction <= 0:
        return np.zeros(shape, dtype=bool)
    field = rng.standard_normal(shape).astype(np.float32)
    field = cv2.GaussianBlur(field, (0, 0), blob_px)
    return field > np.quantile(field, 1.0 - fraction)


def add_depth_noise(depth: np.ndarray, scale: float, rng: np.random.Generator) -> np.ndarray:
    """Gaussian noise with the Kinect v1 axial model (:class:`DepthNoise`'s defaults), times ``scale``."""
    if scale <= 0:
        return depth
    sigma = scale * DepthNoise().sigma_m(depth)
    noisy = depth + sigma * rng.standard_normal(depth.shape).astype(np.float32)
    return np.where(depth > 0, np.maximum(noisy, 0.0), 0.0).astype(np.float32)


def add_depth_holes(depth: np.ndarray, fraction: float, rng: np.random.Generator) -> np.ndarray:
    """Zero out about ``fraction`` of the pixels in blobs (specular / absorbing surfaces)."""
    out = depth.copy()
    out[blob_mask(depth.shape, fraction, rng)] = 0.0
    return out


def add_label_noise(labels: np.ndarray, wrong_fraction: float, erosion_px: int, rng: np.random.Generator) -> np.ndarray:
    """Labeller errors: eroded boundaries and wrongly labelled blobs.

    Every class boundary is set to 0 (unlabelled) over ``erosion_px`` pixels; blobs covering
    ``wrong_fraction`` of the image get another class present in the frame.
    """
    out = labels.copy()
    if erosion_px > 0:
        kernel = np.ones((2 * erosion_px + 1, 2 * erosion_px + 1), np.uint8)
        lab = labels.astype(np.float32)
        boundary = cv2.dilate(lab, kernel) != cv2.erode(lab, kernel)
        out[boundary] = 0
    present = np.unique(labels[labels > 0])
    if wrong_fraction > 0 and present.size > 1:
        mask = blob_mask(labels.shape, wrong_fraction, rng, blob_px=4.0)
        count, comp = cv2.connectedComponents(mask.astype(np.uint8))
        for c in range(1, count):
            region = comp == c
            current = np.bincount(labels[region]).argmax()
            choices = present[present != current]
            out[region & (out > 0)] = rng.choice(choices)
    return out
