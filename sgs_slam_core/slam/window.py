"""The mapping window of a frame: which keyframes it overlaps (chosen by ``keyframes.select_window``), uploaded."""

from __future__ import annotations

from functools import partial

import numpy as np
import torch

from sgs_slam_core.config.sections import KeyframeSettings
from sgs_slam_core.frame import CompactFrame
from sgs_slam_core.frame_data import FrameTensors
from sgs_slam_core.profiling import stage
from sgs_slam_core.semantics import SemanticCodec
from sgs_slam_core.slam.edits import EditLocks
from sgs_slam_core.slam.keyframe_store import KeyframeStore
from sgs_slam_core.slam.keyframes import Window, select_window
from sgs_slam_core.slam.mapper import WindowFrame

__all__ = ["choose_window", "sample_world_points", "upload_window"]


# Current-frame pixels projected into the keyframes to score their overlap, as the released code's
# keyframe selection samples.
OVERLAP_SAMPLES = 1600


def sample_world_points(
    data: FrameTensors, c2w: np.ndarray, count: int, rng: np.random.Generator
) -> np.ndarray:  # [M, 3] float64 world points, M <= count
    """``count`` random pixels with depth of ``data``, back-projected from the camera at ``c2w`` [4, 4]."""
    valid = torch.nonzero(data.valid.reshape(-1)).squeeze(1).cpu().numpy()
    picks = rng.choice(valid, size=min(count, valid.size), replace=False)
    k = data.intrinsics
    v, u = np.divmod(picks, k.width)
    z = data.depth.reshape(-1)[torch.as_tensor(picks, device=data.depth.device)].cpu().numpy().astype(np.float64)
    cam = np.stack([(u - k.cx) / k.fx * z, (v - k.cy) / k.fy * z, z], axis=1)
    return cam @ c2w[:3, :3].T + c2w[:3, 3]


def choose_window(
    store: KeyframeStore,
    data: FrameTensors,
    c2w: np.ndarray,  # [4, 4] the frame's estimated pose
    labels: np.ndarray | None,  # [H, W] the frame's class ids
    settings: KeyframeSettings,
    rng: np.random.Generator,
) -> Window:
    """The keyframes mapped with this frame and the loss weights (SGS-SLAM's overlap and label criteria)."""
    points = sample_world_points(data, c2w, OVERLAP_SAMPLES, rng)
    return select_window(store, points, labels, data.index, settings, rng)


def upload_window(
    store: KeyframeStore,
    window: Window,
    data: FrameTensors,
    c2w: np.ndarray,  # [4, 4] the frame's estimated pose
    codec: SemanticCodec,
    edits: EditLocks,
) -> list[WindowFrame]:
    """The window's keyframes with their poses and weights, the frame itself last.

    Keyframes are decoded on ``data``'s device whenever a mapping step draws them, with the edit
    locks of that moment.
    """
    device = data.depth.device
    frames = []
    for store_index, weight in zip(window.keyframes, window.weights[:-1], strict=True):
        kf = store[store_index]
        w2c = torch.as_tensor(kf.w2c, dtype=torch.float32, device=device)
        frames.append(
            WindowFrame.deferred(partial(_decoded, kf, codec, edits, device), kf.labels is not None, w2c, weight)
        )
    w2c_now = torch.as_tensor(np.linalg.inv(c2w), dtype=torch.float32, device=device)
    frames.append(WindowFrame(data, w2c_now, window.weights[-1]))
    return frames


def _decoded(kf: CompactFrame, codec: SemanticCodec, edits: EditLocks, device: torch.device) -> FrameTensors:
    """A stored keyframe on ``device``, its locked pixels ignored."""
    with stage("upload"):
        data = FrameTensors.from_compact(kf, codec, device)
        return data.with_ignore(edits.ignore_mask(data.labels))
