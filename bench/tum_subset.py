"""Copy the first N colour frames of a TUM RGB-D folder (and their depth and ground truth) elsewhere.

For benchmarks on machines that only receive what travels with the checkout (the GPU suite):

    python bench/tum_subset.py ../shared/data/tum_fr3_teddy .gpu_data/tum_fr3_teddy --frames 60
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

_MARGIN_S = 1.0  # s of depth and ground truth kept beyond the last colour frame (association, interpolation)


def _entries(path: Path) -> tuple[list[str], list[tuple[float, str]]]:
    """Comment lines and (stamp, line) entries of a TUM list file."""
    comments, entries = [], []
    for line in path.read_text().splitlines():
        if line.startswith("#") or not line.strip():
            comments.append(line)
        else:
            entries.append((float(line.split()[0]), line))
    return comments, entries


def copy_subset(src: Path, dst: Path, frames: int) -> int:
    """Copy the first ``frames`` colour frames; returns the bytes copied."""
    dst.mkdir(parents=True, exist_ok=True)
    comments, rgb = _entries(src / "rgb.txt")
    rgb = rgb[:frames]
    first, last = rgb[0][0] - _MARGIN_S, rgb[-1][0] + _MARGIN_S
    copied = 0
    for name in ("rgb.txt", "depth.txt", "groundtruth.txt"):
        comments, entries = _entries(src / name)
        kept = rgb if name == "rgb.txt" else [e for e in entries if first <= e[0] <= last]
        (dst / name).write_text("\n".join([*comments, *(line for _, line in kept)]) + "\n")
        if name != "groundtruth.txt":
            for _, line in kept:
                rel = line.split()[1]
                (dst / rel).parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(src / rel, dst / rel)
                copied += (dst / rel).stat().st_size
    for extra in ("camera.yaml",):
        if (src / extra).is_file():
            shutil.copyfile(src / extra, dst / extra)
    return copied


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("src", type=Path)
    parser.add_argument("dst", type=Path)
    parser.add_argument("--frames", type=int, default=60)
    args = parser.parse_args()
    size = copy_subset(args.src, args.dst, args.frames)
    print(f"copied {args.frames} frames ({size / 2**20:.1f} MiB) to {args.dst}")


if __name__ == "__main__":
    main()
