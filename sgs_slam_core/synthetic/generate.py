"""Generate a synthetic sequence in the SGS-SLAM Replica layout (readable by ``ReplicaDataset``)."""

from __future__ import annotations

import multiprocessing
import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import yaml

from sgs_slam_core.config.loader import config_to_dict
from sgs_slam_core.datasets.camera_file import write_camera_file
from sgs_slam_core.datasets.replica import REPLICA_DEPTH_SCALE
from sgs_slam_core.errors import ConfigError, DatasetError
from sgs_slam_core.fileio import make_dir, write_image, write_text
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.synthetic.noise import add_depth_holes, add_depth_noise, add_label_noise
from sgs_slam_core.synthetic.raycast import raycast
from sgs_slam_core.synthetic.room import build_room
from sgs_slam_core.synthetic.trajectory import TrajectoryKind, make_trajectory

__all__ = ["SYNTH_PRESETS", "SynthConfig", "generate"]


@dataclass(frozen=True)
class SynthConfig:
    """A synthetic sequence.

    Attributes:
        width, height: image size (px); the focal length is 0.75 * width (a 67 degree field of view).
        frames: sequence length.
        trajectory: ``orbit`` (circle, looking across the room), ``walk`` (figure eight, looking
            ahead) or ``look`` (standing, turning the head).
        step_deg: rotation between consecutive frames (deg).
        depth_noise: multiple of the Kinect v1 axial noise model (0 = exact depth).
        depth_holes: fraction of pixels without depth, in blobs.
        label_noise: fraction of pixels relabelled with a wrong class, in blobs.
        label_erosion: class boundaries set to unlabelled over this many pixels.
        supersample: colour sub-samples per pixel side (anti-aliasing).
    """

    width: int = 320
    height: int = 240
    frames: int = 200
    seed: int = 0
    trajectory: TrajectoryKind = "orbit"
    step_deg: float = 1.5
    depth_noise: float = 0.0
    depth_holes: float = 0.0
    label_noise: float = 0.0
    label_erosion: int = 0
    supersample: int = 2

    def __post_init__(self) -> None:
        if self.width < 8 or self.height < 8 or self.frames < 1:
            raise ConfigError(f"need width, height >= 8 and frames >= 1, got {self.width}x{self.height}, {self.frames}")
        if not (0 <= self.depth_holes < 1 and 0 <= self.label_noise < 1):
            raise ConfigError("depth_holes and label_noise are fractions in [0, 1)")
        if self.depth_noise < 0 or self.label_erosion < 0 or self.supersample < 1 or self.step_deg <= 0:
            raise ConfigError("depth_noise, label_erosion >= 0, supersample >= 1, step_deg > 0")

    @property
    def intrinsics(self) -> Intrinsics:
        """The pinhole camera of the sequence."""
        f = 0.75 * self.width
        return Intrinsics(f, f, (self.width - 1) / 2, (self.height - 1) / 2, self.width, self.height)


SYNTH_PRESETS = {
    "tiny": SynthConfig(width=64, height=48, frames=12),
    "room": SynthConfig(width=320, height=240, frames=200),
}


def _prepare(out: Path, overwrite: bool) -> None:
    if out.exists() and any(out.iterdir()):
        if not overwrite:
            raise DatasetError(f"{out} exists and is not empty; use --overwrite (overwrite=True) to replace it")
        shutil.rmtree(out)
    for sub in ("frames", "depths", "semantic_ids", "semantic_colors"):
        make_dir(out / sub)


def _write_frame(job: tuple[Path, SynthConfig, int, np.ndarray]) -> int:
    """Render, degrade and write frame ``i`` (module level so worker processes can run it)."""
    out, config, i, c2w = job
    scene = build_room(config.seed)
    rng = np.random.default_rng([config.seed, i])
    rgb, depth, labels = raycast(scene, config.intrinsics, c2w, config.supersample, config.seed)
    depth = add_depth_holes(add_depth_noise(depth, config.depth_noise, rng), config.depth_holes, rng)
    labels = add_label_noise(labels, config.label_noise, config.label_erosion, rng)
    depth_u16 = np.clip(np.round(depth * REPLICA_DEPTH_SCALE), 0, 65535).astype(np.uint16)
    name = f"{i:06d}.png"
    write_image(out / "frames" / f"frame{name}", rgb[..., ::-1])  # atomic: complete or absent, even on a full disk
    write_image(out / "depths" / f"depth{name}", depth_u16)
    write_image(out / "semantic_ids" / f"semantic_id{name}", labels.astype(np.uint16))
    write_image(out / "semantic_colors" / f"semantic_color{name}", scene.label_table.colorize(labels)[..., ::-1])
    return i


def generate(
    out: str | Path,
    config: SynthConfig,
    overwrite: bool = False,
    progress: Callable[[int, int], None] | None = None,
    workers: int | None = None,
) -> Path:
    """Render ``config`` into ``out`` and return it. Deterministic for a given config.

    Frames are rendered by ``workers`` processes (default: one per CPU core; 1 = in this process).
    """
    out = Path(out)
    _prepare(out, overwrite)
    scene = build_room(config.seed)
    poses = make_trajectory(config.trajectory, config.frames, scene.center, config.step_deg)
    jobs = [(out, config, i, c2w) for i, c2w in enumerate(poses)]
    workers = min(workers or os.cpu_count() or 1, len(jobs))
    if workers > 1 and len(jobs) >= 64:  # below that, starting worker processes costs more than it saves
        with multiprocessing.get_context("spawn").Pool(workers) as pool:
            for done, _ in enumerate(pool.imap_unordered(_write_frame, jobs), 1):
                if progress:
                    progress(done, len(jobs))
    else:
        for done, job in enumerate(jobs, 1):
            _write_frame(job)
            if progress:
                progress(done, len(jobs))
    k = config.intrinsics
    write_camera_file(out / "camera.yaml", k, REPLICA_DEPTH_SCALE)
    write_text(out / "labels.yaml", yaml.safe_dump(scene.label_table.to_dict(), sort_keys=False))
    write_text(out / "synthetic.yaml", yaml.safe_dump(config_to_dict(config), sort_keys=False))
    # last: a sequence without traj.txt is not taken for a Replica folder
    write_text(out / "traj.txt", "".join(" ".join(f"{v:.10f}" for v in p.reshape(-1)) + "\n" for p in poses))
    return out


def preset_config(name: str, **changes: object) -> SynthConfig:
    """A named preset with some fields replaced (None values are ignored)."""
    if name not in SYNTH_PRESETS:
        raise ConfigError(f"unknown synthetic preset {name!r}; known: {', '.join(SYNTH_PRESETS)}")
    return replace(SYNTH_PRESETS[name], **{k: v for k, v in changes.items() if v is not None})
