"""The compiled CPU kernels of a git revision against the working tree's, in one process.

Builds the revision's ``kernels/cpu/raster.cpp`` and ``kernels/cpu/photometric.cpp`` beside the working
tree's (same flags), runs a dataset (default: the synthetic room) for ``--frames`` frames to get a
realistic map, then
times every stage of a mapping render (projection, binning, compositing, its backward, the
parameters' backward) and the SSIM loss, the two builds alternating call by call so both see the
same machine. Checks that both builds agree on the images, gradients and losses to within 1e-5 of
each output's largest entry (a revision may differ by rounding). Prints a table;
does not append to BENCHMARKS.md (a kernel change is recorded with the lever it measures).

    python bench/bench_kernels_ab.py [INPUT --downscale F] [--rev HEAD] [--frames 60] [--repeats 5]
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path
from types import ModuleType

import numpy as np
import torch
from torch.utils.cpp_extension import load

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import REPO, markdown_table
from sgs_slam_core.cli.demo import default_room_dir, ensure_room
from sgs_slam_core.cli.run import default_preset
from sgs_slam_core.config import load_config
from sgs_slam_core.datasets import DatasetOptions, open_dataset
from sgs_slam_core.kernels.cpu.extensions import PHOTOMETRIC, RENDER
from sgs_slam_core.native import _CFLAGS
from sgs_slam_core.slam.system import Slam

SOURCES = {"render": "sgs_slam_core/kernels/cpu/raster.cpp", "photometric": "sgs_slam_core/kernels/cpu/photometric.cpp"}
STAGES = ("prepare", "bin", "forward", "backward", "world backward")


def build_revision(rev: str, key: str, folder: Path) -> ModuleType:
    """The revision's source of ``key`` built under its own module name."""
    src = subprocess.run(
        ["git", "show", f"{rev}:{SOURCES[key]}"], cwd=REPO, capture_output=True, text=True, check=True
    ).stdout
    name = f"bench_{key}_{abs(hash(src)) % 10**10}"
    path = folder / f"{name}.cpp"
    path.write_text(src)
    return load(name=name, sources=[str(path)], extra_cflags=list(_CFLAGS), extra_ldflags=["-fopenmp"])


def render_stages(ext: ModuleType, scene: dict, pose: torch.Tensor, grads: list[torch.Tensor]) -> tuple[dict, list]:
    """Seconds per stage and the outputs (images, rows, parameter gradients) of one render + backward."""
    s, k, th = scene["settings"], scene["k"], torch.get_num_threads()
    cam = (k.fx, k.fy, k.cx, k.cy, k.width, k.height)
    times, t = {}, time.perf_counter()
    mc, sc, op, feats, m2d, con, rad = ext.prepare_world_isotropic(
        *scene["params"], pose, *cam, s.near_plane, s.eps2d, s.alpha_min, s.extent_sigma, th
    )
    times["prepare"], t = time.perf_counter() - t, time.perf_counter()
    try:
        gids, offsets = ext.bin_gaussians(m2d, rad, feats[:, -1], k.width, k.height, 32, th)
    except TypeError:  # builds before the thread count argument
        gids, offsets = ext.bin_gaussians(m2d, rad, feats[:, -1], k.width, k.height, 32)
    times["bin"], t = time.perf_counter() - t, time.perf_counter()
    args = (k.width, k.height, 32, s.alpha_min, s.alpha_max, s.extent_sigma**2, s.min_transmittance, th)
    groups = [3, scene["params"][4].shape[1], 1]
    *images, _, t_final, count = ext.composite_forward(m2d, con, op, rad, feats, gids, offsets, groups, *args)
    times["forward"], t = time.perf_counter() - t, time.perf_counter()
    rows = ext.composite_backward(m2d, con, op, rad, feats, gids, offsets, t_final, count, groups, grads, None, *args)
    times["backward"], t = time.perf_counter() - t, time.perf_counter()
    try:
        g = ext.world_isotropic_backward(
            scene["params"][0], pose, mc, sc, op, rows, groups[1], True, False, *cam, s.near_plane, s.eps2d, th
        )
    except TypeError:  # builds before need_params
        g = ext.world_isotropic_backward(
            scene["params"][0], pose, mc, sc, op, rows, groups[1], False, *cam, s.near_plane, s.eps2d, th
        )
    times["world backward"] = time.perf_counter() - t
    return times, [*images, rows, *g[:5]]


def map_scene(source: Path | None, downscale: float | None, frames: int) -> dict:
    """The map after ``frames`` frames of ``source`` (None: the room) and its last 20 keyframe-like poses."""
    folder = source or ensure_room(default_room_dir())
    dataset = open_dataset(folder, "auto", DatasetOptions(downscale=downscale or (2.0 if source is None else 1.0)))
    config = load_config(default_preset(folder, "auto"), None, ["device=cpu"])
    torch.manual_seed(config.seed)
    slam = Slam(config, dataset.label_table)
    for i in range(frames):
        slam.process(dataset[i])
    g = slam.gaussians
    poses = [torch.as_tensor(np.linalg.inv(c2w), dtype=torch.float32) for _, _, c2w in slam.trajectory[-20:]]
    semantics = g.semantics if dataset[0].labels is not None else g.semantics[:, :0]  # unlabelled: not rendered
    params = [t.detach().contiguous() for t in (g.means, g.log_scales, g.logit_opacities, g.colors, semantics)]
    return {"params": params, "poses": poses, "k": dataset.intrinsics, "settings": config.render, "frames": frames}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("input", nargs="?", type=Path, help="dataset folder (default: the synthetic room)")
    parser.add_argument("--downscale", type=float, help="divide the image size by F (room default: 2 = 160x120)")
    parser.add_argument("--rev", default="HEAD", help="git revision to compare the working tree with")
    parser.add_argument("--frames", type=int, default=60, help="room frames mapped before timing")
    parser.add_argument("--repeats", type=int, default=5, help="passes over the 20 poses")
    parser.add_argument("--scene", type=Path, help="map file: loaded when it exists, else written after the run")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        old = {key: build_revision(args.rev, key, Path(folder)) for key in SOURCES}
    new = {"render": RENDER.module(), "photometric": PHOTOMETRIC.module()}
    if args.scene and args.scene.exists():
        scene = torch.load(args.scene, weights_only=False)
    else:
        scene = map_scene(args.input, args.downscale, args.frames)
        if args.scene:
            torch.save(scene, args.scene)
    k, gen = scene["k"], torch.Generator().manual_seed(0)
    times: dict[tuple[str, str], list[float]] = defaultdict(list)
    for rep in range(args.repeats):
        for i, pose in enumerate(scene["poses"]):
            grads = [torch.randn(k.height, k.width, c, generator=gen) for c in (3, scene["params"][4].shape[1], 1)]
            x, y = torch.rand(k.height, k.width, 3, generator=gen), torch.rand(k.height, k.width, 3, generator=gen)
            outs = {}
            for side in ("old", "new") if (rep + i) % 2 else ("new", "old"):
                ext = old if side == "old" else new
                stage_s, out = render_stages(ext["render"], scene, pose, grads)
                for stage, sec in stage_s.items():
                    times[side, stage].append(sec)
                t = time.perf_counter()
                out += ext["photometric"].photometric_loss(x, y, 0.2, 11, 1.5, True, torch.get_num_threads())
                times[side, "SSIM loss"].append(time.perf_counter() - t)
                outs[side] = out
            for j, (a, b) in enumerate(zip(outs["old"], outs["new"], strict=True)):
                if a.numel() and (a - b).abs().max() > 1e-5 * a.abs().max():
                    raise SystemExit(f"the builds disagree at pose {i} (output {j})")
    rows = []
    for stage in (*STAGES, "SSIM loss"):
        a, b = (statistics.median(times[side, stage]) * 1e3 for side in ("old", "new"))
        rows.append([stage, f"{a:.2f}", f"{b:.2f}", f"{b / a:.3f}"])
    n = scene["params"][0].shape[0]
    where = args.input.name if args.input else (f"map {args.scene.name}" if args.scene else "room")
    print(
        f"{args.rev} vs working tree, {where} after {scene.get('frames', args.frames)} frames ({n:,} Gaussians), "
        f"{k.width}x{k.height}, {args.repeats} x 20 poses, medians:\n"
    )
    print(markdown_table(["stage", f"{args.rev} ms", "working tree ms", "ratio"], rows))


if __name__ == "__main__":
    main()
