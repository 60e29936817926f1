"""Sparse image features on RGB-D frames: ORB keypoints with their depth, matched and solved by PnP.

What the frames themselves say about the camera's motion, independently of the map: the motion
model starts tracking from a feature pose when the constant-velocity guess disagrees with it, the
guard checks a tracked pose against the features, and relocalization matches a lost frame against
the keyframes' features. OpenCV (already a dependency) does the detection, the matching and the
RANSAC PnP; everything here works on host arrays, as OpenCV does.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from sgs_slam_core.config.sections import FeatureSettings
from sgs_slam_core.geometry.camera import Intrinsics

__all__ = [
    "MAX_DISTANCE",
    "FeatureMotion",
    "FrameFeatures",
    "Landmarks",
    "Matches",
    "agreement",
    "extract_features",
    "inlier_landmarks",
    "match_features",
    "solve_motion",
]

ORB_LEVELS = 3  # ORB pyramid levels (1.2 apart)
MAX_DISTANCE = 64  # matches whose descriptors differ in more bits (of 256) are dropped
RANSAC_ITERATIONS = 100  # RANSAC hypotheses per PnP solve
_RATIO = 0.8  # Lowe's ratio test: the best match must be this much closer than the second best
_DEPTH_SEARCH = ((0, 0), (1, 0), (-1, 0), (0, 1), (0, -1))  # a keypoint on a depth hole takes a neighbour's depth


@dataclass(frozen=True)
class FrameFeatures:
    """One frame's ORB keypoints, descriptors and back-projected points."""

    keypoints: np.ndarray  # [N, 2] float64 pixel coordinates (u, v)
    descriptors: np.ndarray  # [N, 32] uint8 ORB descriptors
    points: np.ndarray  # [N, 3] float64 camera-frame points (m); z = 0 where the depth is missing
    intrinsics: Intrinsics

    def __len__(self) -> int:
        return len(self.keypoints)

    @property
    def has_depth(self) -> np.ndarray:  # [N] bool
        """Keypoints with a 3D point."""
        return self.points[:, 2] > 0


@dataclass(frozen=True)
class Matches:
    """Index pairs into a reference and a query :class:`FrameFeatures`."""

    reference: np.ndarray  # [M] int64
    query: np.ndarray  # [M] int64

    def __len__(self) -> int:
        return len(self.reference)


@dataclass(frozen=True)
class FeatureMotion:
    """A pose solved from feature matches: where the query camera is relative to the reference camera."""

    ref_to_query: np.ndarray  # [4, 4] float64: reference camera frame -> query camera frame
    inliers: int  # matches within the reprojection threshold at the pose
    matches: int  # matches with a reference point (the RANSAC's candidates)


@dataclass(frozen=True)
class Landmarks:
    """Map-frame points and the pixels where one frame sees them: a feature pose's inlier matches.

    A tracker can hold its pose to them beside the dense terms (``tracking.gauss_newton.feature_weight``).
    """

    points: np.ndarray  # [M, 3] float64, map frame (m)
    pixels: np.ndarray  # [M, 2] float64, in the frame (px, u v)
    huber_px: float  # reprojection errors beyond this (px) count less

    def __len__(self) -> int:
        return len(self.points)


def _camera_matrix(k: Intrinsics) -> np.ndarray:  # [3, 3]
    return np.array([[k.fx, 0.0, k.cx], [0.0, k.fy, k.cy], [0.0, 0.0, 1.0]])


def _detector(settings: FeatureSettings, width: int) -> cv2.ORB:
    """ORB sized to the image: a 160-pixel-wide frame gets a 15-pixel patch, 320 and more OpenCV's 31."""
    patch = int(np.clip(round(31 * width / 320), 15, 31))
    return cv2.ORB_create(
        nfeatures=settings.count,
        scaleFactor=1.2,
        nlevels=ORB_LEVELS,
        edgeThreshold=patch,
        patchSize=patch,
        fastThreshold=settings.fast_threshold,
    )


def _depth_at(depth: np.ndarray, uv: np.ndarray) -> np.ndarray:  # [H, W] m, [N, 2] -> [N] m
    """Depth at the nearest pixel of each keypoint; where that is missing, a valid 4-neighbour's."""
    h, w = depth.shape
    u0, v0 = np.floor(uv[:, 0] + 0.5).astype(np.int64), np.floor(uv[:, 1] + 0.5).astype(np.int64)
    z = np.zeros(len(uv))
    for du, dv in _DEPTH_SEARCH:
        u, v = np.clip(u0 + du, 0, w - 1), np.clip(v0 + dv, 0, h - 1)
        z = np.where(z > 0, z, depth[v, u])
    return z


def extract_features(
    rgb: np.ndarray,  # [H, W, 3] uint8
    depth: np.ndarray,  # [H, W] float32 m, 0 = invalid
    intrinsics: Intrinsics,
    settings: FeatureSettings,
) -> FrameFeatures:
    """ORB keypoints of the frame's intensity, each with its depth back-projected (z = 0 without)."""
    gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    keypoints, descriptors = _detector(settings, intrinsics.width).detectAndCompute(gray, None)
    if descriptors is None or not keypoints:
        uv, descriptors = np.zeros((0, 2)), np.zeros((0, 32), np.uint8)
    else:
        uv = np.array([kp.pt for kp in keypoints], dtype=np.float64)
    z = _depth_at(depth, uv) if len(uv) else np.zeros(0)
    k = intrinsics
    points = np.stack([(uv[:, 0] - k.cx) / k.fx * z, (uv[:, 1] - k.cy) / k.fy * z, z], axis=1)
    return FrameFeatures(uv, descriptors, points, intrinsics)


def match_features(reference: FrameFeatures, query: FrameFeatures, max_distance: int) -> Matches:
    """Nearest neighbours by Hamming distance, at most ``max_distance`` bits apart and distinct.

    Distinct: clearly nearer than the second nearest (Lowe's ratio test), and no query keypoint
    matched twice. Only reference keypoints with a 3D point take part: the others serve no pose.
    """
    usable = np.flatnonzero(reference.has_depth)
    if not len(usable) or len(query) < 2:
        return Matches(np.zeros(0, np.int64), np.zeros(0, np.int64))
    # one pass of two nearest neighbours with Lowe's ratio test: half the time of OpenCV's cross check
    pairs = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(reference.descriptors[usable], query.descriptors, k=2)
    best = np.array([[p[0].queryIdx, p[0].trainIdx, p[0].distance, p[1].distance] for p in pairs if len(p) == 2])
    if not len(best):
        return Matches(np.zeros(0, np.int64), np.zeros(0, np.int64))
    best = best[(best[:, 2] <= max_distance) & (best[:, 2] < _RATIO * best[:, 3])]
    best = best[np.argsort(best[:, 2], kind="stable")]
    _, first = np.unique(best[:, 1], return_index=True)  # a query keypoint keeps its closest match only
    best = best[np.sort(first)]
    return Matches(usable[best[:, 0].astype(np.int64)], best[:, 1].astype(np.int64))


def _reprojection_errors(
    points: np.ndarray, pixels: np.ndarray, ref_to_query: np.ndarray, k: Intrinsics
) -> np.ndarray:  # [M, 3] reference points, [M, 2] query pixels -> [M] px
    """Distance (px) between each query keypoint and its reference point projected at ``ref_to_query``."""
    p = points @ ref_to_query[:3, :3].T + ref_to_query[:3, 3]
    z = p[:, 2]
    in_front = z > 1e-6
    zs = np.where(in_front, z, 1.0)
    uv = np.stack([p[:, 0] / zs * k.fx + k.cx, p[:, 1] / zs * k.fy + k.cy], axis=1)
    return np.where(in_front, np.linalg.norm(uv - pixels, axis=1), np.inf)


def solve_motion(
    reference: FrameFeatures, query: FrameFeatures, matches: Matches, settings: FeatureSettings
) -> FeatureMotion | None:
    """The query camera relative to the reference one by RANSAC PnP on the reference's 3D points.

    None when fewer than ``settings.min_inliers`` matches agree. The pose is refined
    (Levenberg-Marquardt) on its inliers.
    """
    points, pixels = _matched(reference, query, matches)
    if len(points) < max(settings.min_inliers, 6):
        return None
    camera = _camera_matrix(query.intrinsics)
    ok, rvec, tvec, inliers = cv2.solvePnPRansac(
        points,
        pixels,
        camera,
        None,
        iterationsCount=RANSAC_ITERATIONS,
        reprojectionError=settings.reprojection_px,
        confidence=0.999,
        flags=cv2.SOLVEPNP_EPNP,
    )
    if not ok or inliers is None or len(inliers) < settings.min_inliers:
        return None
    inliers = inliers.ravel()
    rvec, tvec = cv2.solvePnPRefineLM(points[inliers], pixels[inliers], camera, None, rvec, tvec)
    pose = np.eye(4)
    pose[:3, :3] = cv2.Rodrigues(rvec)[0]
    pose[:3, 3] = tvec.ravel()
    count = int((_reprojection_errors(points, pixels, pose, query.intrinsics) <= settings.reprojection_px).sum())
    if count < settings.min_inliers:
        return None
    return FeatureMotion(pose, count, len(points))


def _matched(reference: FrameFeatures, query: FrameFeatures, matches: Matches) -> tuple[np.ndarray, np.ndarray]:
    """The reference points [M, 3] and query pixels [M, 2] of the matches whose reference has depth."""
    with_depth = reference.has_depth[matches.reference]
    return reference.points[matches.reference[with_depth]], query.keypoints[matches.query[with_depth]]


def agreement(
    reference: FrameFeatures, query: FrameFeatures, matches: Matches, ref_to_query: np.ndarray, threshold_px: float
) -> int:
    """How many of the matches (with a reference point) lie within ``threshold_px`` of their projection."""
    points, pixels = _matched(reference, query, matches)
    return int((_reprojection_errors(points, pixels, ref_to_query, query.intrinsics) <= threshold_px).sum())


def inlier_landmarks(
    reference: FrameFeatures,
    query: FrameFeatures,
    matches: Matches,
    ref_to_query: np.ndarray,  # [4, 4] the pose the inliers agree with
    ref_c2w: np.ndarray,  # [4, 4] the reference camera in the map frame
    threshold_px: float,
) -> Landmarks:
    """The matches within ``threshold_px`` of their projection at ``ref_to_query``, as map-frame landmarks."""
    points, pixels = _matched(reference, query, matches)
    keep = _reprojection_errors(points, pixels, ref_to_query, query.intrinsics) <= threshold_px
    world = points[keep] @ ref_c2w[:3, :3].T + ref_c2w[:3, 3]
    return Landmarks(world, pixels[keep].astype(np.float64), threshold_px)
