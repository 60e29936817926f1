"""What makes a run folder comparable: the ground truth in TUM format and ``run.yaml``'s provenance.

``groundtruth.txt`` holds the dataset's ground-truth camera-to-world poses at the stamps of
``trajectory.txt`` (frames without ground truth are left out), so ``evo_ape tum groundtruth.txt
trajectory.txt -a`` reproduces our ATE. ``run.yaml`` records the input and options (for
``sgs-slam eval``) plus where the numbers came from: git commit of the source, package versions,
device and date.
"""

from __future__ import annotations

import datetime
import os
import platform
import subprocess
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np
import torch

from sgs_slam_core.metrics.trajectory_io import write_tum_trajectory

__all__ = ["GROUND_TRUTH_FILE", "device_info", "environment", "git_info", "write_ground_truth"]

GROUND_TRUTH_FILE = "groundtruth.txt"
_PACKAGES = ("sgs_slam_ros", "torch", "numpy", "opencv-python-headless", "gsplat", "rosbags", "mcap")
_SOURCE_DIR = Path(__file__).resolve().parents[2]  # the checkout holding sgs_slam_core


def write_ground_truth(path: Path, stamps_ns: list[int], gt_c2w: list[np.ndarray | None]) -> int:
    """Write the frames that have ground truth in TUM format; returns how many (0: no file written)."""
    pairs = [(s, g) for s, g in zip(stamps_ns, gt_c2w, strict=True) if g is not None]
    if not pairs:
        return 0
    write_tum_trajectory(path, [s for s, _ in pairs], np.stack([g for _, g in pairs]))
    return len(pairs)


def _git(*args: str) -> str | None:
    try:
        out = subprocess.run(
            ["git", "-C", str(_SOURCE_DIR), *args], capture_output=True, text=True, timeout=10, check=False
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() if out.returncode == 0 else None


def git_info() -> dict[str, Any] | None:
    """Commit, branch and whether tracked files differ from it; None unless running from a git checkout.

    An installed copy (site-packages, a colcon install space) has no commit of its own, even when it
    sits inside some other repository.
    """
    top = _git("rev-parse", "--show-toplevel")
    if top is None or Path(top).resolve() != _SOURCE_DIR:
        return None
    commit = _git("rev-parse", "HEAD")
    if commit is None:  # a repository without commits
        return None
    status = _git("status", "--porcelain", "--untracked-files=no")
    return {"commit": commit, "branch": _git("rev-parse", "--abbrev-ref", "HEAD"), "dirty": bool(status)}


def _cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def device_info(device: torch.device) -> dict[str, Any]:
    """The compute device: CUDA name, capability and memory, or the CPU model and thread count."""
    info: dict[str, Any] = {"type": device.type}
    if device.type == "cuda":
        props = torch.cuda.get_device_properties(device)
        info.update(
            name=props.name,
            capability=f"{props.major}.{props.minor}",
            memory_gib=round(props.total_memory / 2**30, 1),
            cuda=torch.version.cuda,
        )
    else:
        info.update(name=_cpu_name(), threads=torch.get_num_threads(), cores=os.cpu_count())
    return info


def environment(device: torch.device) -> dict[str, Any]:
    """Provenance of a run: date (UTC), git, python and package versions, device, host."""
    versions: dict[str, str] = {"python": platform.python_version()}
    for name in _PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return {
        "created_utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),  # noqa: UP017 - 3.10
        "git": git_info(),
        "versions": versions,
        "device": device_info(device),
        "host": platform.node(),
        "platform": platform.platform(),
    }
