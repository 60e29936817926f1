"""A classic peer side by side: Open3D's frame-to-frame RGB-D odometry against this SLAM's tracking.

Open3D is a benchmark-only dependency (``pip install open3d``; on a machine without ``libusb-1.0``
its import fails, install the system library). Both run on the same frames of one input at the
same size, in one process: Open3D's ``compute_rgbd_odometry`` (hybrid photometric + geometric term,
its default pyramid) chained frame to frame, and ``--ours`` a lockstep SLAM run with this project's
configuration (``--set tracking.method=...``). Prints ms per frame of tracking and the ATE of each
(camera centres after SE(3) alignment) and appends the table to BENCHMARKS.md.

    python bench/bench_open3d.py ../shared/data/tum_fr3_teddy --downscale 4 [--ours] [--set KEY=VALUE]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import append_section, markdown_table
from sgs_slam_core.cli.run import default_preset
from sgs_slam_core.config import load_config
from sgs_slam_core.datasets import DatasetOptions, open_dataset
from sgs_slam_core.datasets.base import Dataset
from sgs_slam_core.metrics import ate
from sgs_slam_core.runner import run_offline


def open3d_odometry(dataset: Dataset) -> tuple[list[float], np.ndarray, np.ndarray]:
    """Per-frame ms, estimated c2w [T, 4, 4] and ground truth [T, 4, 4] (frames with ground truth)."""
    import open3d as o3d  # noqa: PLC0415 - benchmark-only dependency

    k = dataset.intrinsics
    camera = o3d.camera.PinholeCameraIntrinsic(k.width, k.height, k.fx, k.fy, k.cx, k.cy)
    option = o3d.pipelines.odometry.OdometryOption()
    jacobian = o3d.pipelines.odometry.RGBDOdometryJacobianFromHybridTerm()

    def rgbd(i: int) -> o3d.geometry.RGBDImage:
        f = dataset[i]
        color = o3d.geometry.Image(np.ascontiguousarray(f.rgb))
        depth = o3d.geometry.Image(np.ascontiguousarray(f.depth.astype(np.float32)))
        return o3d.geometry.RGBDImage.create_from_color_and_depth(
            color, depth, depth_scale=1.0, convert_rgb_to_intensity=True
        )

    poses, truth, times = [np.eye(4)], [dataset[0].gt_c2w], []
    previous = rgbd(0)
    for i in range(1, len(dataset)):
        current = rgbd(i)
        t0 = time.perf_counter()
        ok, cur_to_prev_inv, _ = o3d.pipelines.odometry.compute_rgbd_odometry(
            current, previous, camera, np.eye(4), jacobian, option
        )
        times.append((time.perf_counter() - t0) * 1e3)
        # the transform maps the source (current) frame's points into the target (previous) frame
        poses.append(poses[-1] @ (cur_to_prev_inv if ok else np.eye(4)))
        truth.append(dataset[i].gt_c2w)
        previous = current
    keep = [i for i, t in enumerate(truth) if t is not None]
    return times, np.stack([poses[i] for i in keep]), np.stack([truth[i] for i in keep])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("input", type=Path, help="dataset folder or MCAP bag")
    parser.add_argument("--downscale", type=float, default=1.0, help="divide the image size by F")
    parser.add_argument("--max-frames", type=int, help="process at most N frames")
    parser.add_argument("--ours", action="store_true", help="also run this SLAM in lockstep on the same frames")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--no-append", action="store_true", help="print only, do not append to BENCHMARKS.md")
    args = parser.parse_args()
    dataset = open_dataset(args.input, "auto", DatasetOptions(max_frames=args.max_frames, downscale=args.downscale))
    k = dataset.intrinsics
    times, est, gt = open3d_odometry(dataset)
    rows = [
        [
            "Open3D RGB-D odometry (hybrid, frame to frame)",
            f"{np.median(times):.1f}",
            f"{np.mean(times):.1f}",
            f"{ate(est, gt).rmse * 100:.2f}",
        ]
    ]
    if args.ours:
        preset = default_preset(args.input, "auto")
        config = load_config(preset, None, [*args.overrides, "device=cpu"])
        out = Path(tempfile.mkdtemp(prefix="bench_open3d_"))
        result = run_offline(dataset, config, out, overwrite=True, provenance={"bench": True}, show_progress=False)
        track = [s.track.time_s * 1e3 for s in result.steps[1:]]
        name = f"this SLAM, tracking.method={config.tracking.method} (preset {preset})"
        rows.append(
            [name, f"{np.median(track):.1f}", f"{np.mean(track):.1f}", f"{result.metrics['ate_rmse_m'] * 100:.2f}"]
        )
    body = (
        f"{dataset.name}, {len(dataset)} frames at {k.width}x{k.height}, same process:\n\n"
        + markdown_table(["method", "tracking ms/frame (median)", "mean", "ATE RMSE (cm)"], rows)
        + f"\n\nOverrides: {args.overrides or 'none'}.\n"
    )
    print(body)
    if not args.no_append:
        append_section(f"Open3D odometry side by side: {dataset.name} {k.width}x{k.height}", body)


if __name__ == "__main__":
    main()
