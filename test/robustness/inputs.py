"""Builders of broken inputs, each from the tiny synthetic scene or a finished run, made in a test's tmp folder."""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch
import yaml

from bags import convert
from sgs_slam_core.datasets import open_dataset
from sgs_slam_core.mapio import load_map, write_any_map

# CI-sized runs: a few frames, a few iterations (the matrix checks outcomes, not accuracy)
FAST_RUN = ("--max-frames", "3", "--quiet", "--set", "tracking.adam.iterations=3", "--set", "mapping.iterations=3")


@dataclass(frozen=True)
class Env:
    """What a case builds from: a scratch folder and shared inputs it must not modify."""

    tmp: Path
    tiny: Path  # the tiny synthetic scene (SGS-SLAM Replica layout, 12 frames of 64x48)
    run: Path  # a finished run of the tiny scene
    bag: Path  # the tiny scene as an MCAP bag

    def copy(self, src: Path, name: str) -> Path:
        """A private copy of ``src`` (a folder or a file) under ``tmp``."""
        dst = self.tmp / name
        if src.is_dir():
            shutil.copytree(src, dst)
        else:
            shutil.copyfile(src, dst)
        return dst

    def path(self, name: str) -> str:
        """``tmp / name`` as a command-line argument."""
        return str(self.tmp / name)


# ---------------------------------------------------------------------------------------------- TUM
def tum_from_tiny(env: Env, frames: int = 3, name: str = "rgbd_dataset_freiburg3_tiny") -> Path:
    """The first ``frames`` frames of the tiny scene as a TUM folder (depth / 5000, ground truth as quaternions)."""
    root = env.tmp / name
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    ds = open_dataset(env.tiny)
    rgb_lines, depth_lines, gt_lines = ["# color images"], ["# depth maps"], ["# timestamp tx ty tz qx qy qz qw"]
    for i in range(frames):
        f = ds[i]
        t = 1.0 + i / 30
        cv2.imwrite(str(root / "rgb" / f"{t:.6f}.png"), f.rgb[..., ::-1])
        cv2.imwrite(str(root / "depth" / f"{t:.6f}.png"), np.round(f.depth * 5000).astype(np.uint16))
        rgb_lines.append(f"{t:.6f} rgb/{t:.6f}.png")
        depth_lines.append(f"{t:.6f} depth/{t:.6f}.png")
        q = _quat_xyzw(f.gt_c2w[:3, :3])
        gt_lines.append(f"{t:.6f} " + " ".join(f"{v:.9f}" for v in (*f.gt_c2w[:3, 3], *q)))
    (root / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (root / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    (root / "groundtruth.txt").write_text("\n".join(gt_lines) + "\n")
    k = ds.intrinsics
    (root / "camera.yaml").write_text(
        yaml.safe_dump({"width": k.width, "height": k.height, "fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy})
    )
    return root


def _quat_xyzw(r: np.ndarray) -> tuple[float, float, float, float]:
    w = np.sqrt(max(1.0 + np.trace(r), 1e-12)) / 2
    return ((r[2, 1] - r[1, 2]) / (4 * w), (r[0, 2] - r[2, 0]) / (4 * w), (r[1, 0] - r[0, 1]) / (4 * w), w)


def tum_latin1(env: Env) -> Path:
    """A TUM folder whose rgb.txt is Latin-1, with an accented comment and accented file names."""
    root = tum_from_tiny(env)
    lines = ["# Farbbilder, aufgenommen f\xfcr den Test (Latin-1)"]
    for line in (root / "rgb.txt").read_text().splitlines()[1:]:
        stamp, name = line.split()
        accented = name.replace("rgb/", "rgb/caf\xe9_")
        (root / name).rename(root / accented.encode("latin-1").decode("utf-8", "surrogateescape"))
        lines.append(f"{stamp} {accented}")
    (root / "rgb.txt").write_bytes(("\n".join(lines) + "\n").encode("latin-1"))
    return root


# ---------------------------------------------------------------------------------------------- Replica
def replica_with(env: Env, name: str, file: str, content: str | bytes) -> Path:
    """A copy of the tiny scene with ``file`` replaced by ``content``."""
    root = env.copy(env.tiny, name)
    target = root / file
    target.write_bytes(content if isinstance(content, bytes) else content.encode())
    return root


def replica_non_rigid(env: Env) -> Path:
    """traj.txt whose third pose has a scaled, singular rotation (a row of zeros)."""
    root = env.copy(env.tiny, "non_rigid")
    rows = (root / "traj.txt").read_text().splitlines()
    values = [float(v) for v in rows[2].split()]
    values[0:3] = [0.0, 0.0, 0.0]
    rows[2] = " ".join(f"{v:.10f}" for v in values)
    (root / "traj.txt").write_text("\n".join(rows) + "\n")
    return root


# ---------------------------------------------------------------------------------------------- ScanNet
def scannet_tiny(env: Env, tsv: bytes | None = None, pose_1: str | None = None, intrinsic: str | None = None) -> Path:
    """A 3-frame ScanNet export (64x48) with optional replacements of the TSV, pose 1 and intrinsics."""
    root = env.tmp / "scans" / "scene0000_00"
    for sub in ("color", "depth", "pose", "intrinsic", "label-filt"):
        (root / sub).mkdir(parents=True)
    k = np.eye(4)
    k[0, 0], k[1, 1], k[0, 2], k[1, 2] = 48.0, 48.0, 31.5, 23.5
    (root / "intrinsic" / "intrinsic_color.txt").write_text(intrinsic or "\n".join(" ".join(map(str, r)) for r in k))
    for i in range(3):
        cv2.imwrite(str(root / "color" / f"{i}.jpg"), np.full((48, 64, 3), 128, np.uint8))
        cv2.imwrite(str(root / "depth" / f"{i}.png"), np.full((48, 64), 1500, np.uint16))
        cv2.imwrite(str(root / "label-filt" / f"{i}.png"), np.ones((48, 64), np.uint16))
        pose = "\n".join(" ".join(map(str, r)) for r in np.eye(4))
        (root / "pose" / f"{i}.txt").write_text(pose_1 if i == 1 and pose_1 is not None else pose)
    (root.parent / "scannetv2-labels.combined.tsv").write_bytes(
        tsv or b"id\traw_category\tcategory\tcount\tnyu40id\tnyu40class\n1\twall\twall\t10\t1\twall\n"
    )
    return root


# ---------------------------------------------------------------------------------------------- bags
def bag_with_metadata(env: Env, name: str, **custom: str) -> Path:
    """A copy of the tiny bag with these custom_data entries in metadata.yaml."""
    bag = env.copy(env.bag, name)
    meta_file = bag / "metadata.yaml"
    meta = yaml.safe_load(meta_file.read_text())
    meta["rosbag2_bagfile_information"].setdefault("custom_data", {}).update(custom)
    meta_file.write_text(yaml.safe_dump(meta))
    return bag


def bag_with_label_65535(env: Env) -> Path:
    """The tiny scene as a bag whose second frame has a pixel of class 65535."""
    scene = env.copy(env.tiny, "scene_65535")
    label_file = sorted((scene / "semantic_ids").glob("*.png"))[1]
    labels = cv2.imread(str(label_file), cv2.IMREAD_UNCHANGED)
    labels[5, 5] = 65535
    cv2.imwrite(str(label_file), labels)
    bag = env.tmp / "bag_65535"
    convert(open_dataset(scene), bag, compress=False, max_frames=3)
    return bag


# ---------------------------------------------------------------------------------------------- run folders
def run_with_yaml(env: Env, name: str, text: str | None = None, **changes: object) -> Path:
    """A copy of the finished run with run.yaml replaced by ``text`` or updated with ``changes``."""
    run = env.copy(env.run, name)
    if text is None:
        data = yaml.safe_load((run / "run.yaml").read_text())
        data.update(changes)
        text = yaml.safe_dump(data)
    (run / "run.yaml").write_text(text)
    return run


def run_with_metrics(env: Env, name: str, text: str) -> Path:
    """A copy of the finished run with metrics.json replaced by ``text``."""
    run = env.copy(env.run, name)
    (run / "metrics.json").write_text(text)
    return run


# ---------------------------------------------------------------------------------------------- maps
def ply_with_header(env: Env, name: str, old: str, new: str) -> Path:
    """The run's map.ply with one header line replaced (the binary body untouched)."""
    raw = (env.run / "map.ply").read_bytes()
    end = raw.index(b"end_header\n")
    header = raw[:end].decode("ascii")
    assert old in header, old
    out = env.tmp / name
    out.write_bytes(header.replace(old, new, 1).encode("ascii") + raw[end:])
    return out


def ply_with_nan(env: Env) -> Path:
    """The run's map.ply with the first Gaussian's x set to NaN."""
    raw = bytearray((env.run / "map.ply").read_bytes())
    start = raw.index(b"end_header\n") + len(b"end_header\n")
    raw[start : start + 4] = np.array([np.nan], "<f4").tobytes()  # x is the first property
    out = env.tmp / "nan.ply"
    out.write_bytes(bytes(raw))
    return out


def sgsmap_with(env: Env, name: str, **changes: object) -> Path:
    """The run's map.sgsmap with top-level fields replaced (e.g. a string where a number belongs)."""
    data = torch.load(env.run / "map.sgsmap", weights_only=True)
    data.update(changes)
    out = env.tmp / name
    torch.save(data, out)
    return out


def map_with_unknown_labels(env: Env, suffix: str) -> Path:
    """The run's map with 20 Gaussians of class 101, absent from its label table and above NYU40."""
    saved = load_map(env.run / "map.sgsmap")
    saved.gaussians.labels[:20] = 101
    out = env.tmp / f"unknown_labels{suffix}"
    write_any_map(out, saved)
    table = json.dumps(saved.label_table.to_dict())
    assert '"id": 101' not in table
    return out
