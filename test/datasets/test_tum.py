import math

import cv2
import numpy as np
import pytest

from sgs_slam_core.datasets import DatasetOptions, TumDataset, open_dataset
from sgs_slam_core.datasets.tum import TUM_INTRINSICS, associate
from sgs_slam_core.errors import DatasetError


def write_tum(root, rgb_stamps, depth_stamps, gt_rows, size=(640, 480)):
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    w, h = size
    for t in rgb_stamps:
        cv2.imwrite(str(root / "rgb" / f"{t:.6f}.png"), np.full((h, w, 3), 100, np.uint8))
    for t in depth_stamps:
        cv2.imwrite(str(root / "depth" / f"{t:.6f}.png"), np.full((h, w), 5000, np.uint16))  # 1 m
    (root / "rgb.txt").write_text("# color images\n" + "".join(f"{t:.6f} rgb/{t:.6f}.png\n" for t in rgb_stamps))
    (root / "depth.txt").write_text("# depth\n" + "".join(f"{t:.6f} depth/{t:.6f}.png\n" for t in depth_stamps))
    (root / "groundtruth.txt").write_text("# gt\n" + "".join(" ".join(map(str, r)) + "\n" for r in gt_rows))


@pytest.fixture
def tum_folder(tmp_path):
    root = tmp_path / "rgbd_dataset_freiburg2_xyz"
    rgb = [1.000, 1.033, 1.066, 1.100, 1.133]
    depth = [1.005, 1.030, 1.096, 1.104, 1.140]  # 1.066: its nearest depths (1.030, 1.096) are 36 and 30 ms away
    gt = [  # starts after the first RGB frame; 45 deg about z between 1.02 and 1.11 (qx qy qz qw)
        (1.02, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0),
        (1.11, 1.0, 2.0, 0.0, 0.0, 0.0, math.sin(math.pi / 8), math.cos(math.pi / 8)),
    ]
    write_tum(root, rgb, depth, gt)
    return root


def test_association_interpolation_and_gt_span(tum_folder):
    ds = TumDataset(tum_folder)
    stamps = [r.stamp_ns / 1e9 for r in ds.records]
    assert stamps == pytest.approx([1.000, 1.033, 1.100, 1.133])
    assert ds.intrinsics == TUM_INTRINSICS["fr2"]  # from the folder name
    first, second, third, fourth = (ds[i] for i in range(4))
    assert first.gt_c2w is None  # before the first ground-truth stamp
    assert fourth.gt_c2w is None  # after the last one
    s = (1.033 - 1.02) / 0.09
    assert second.gt_c2w[:3, 3] == pytest.approx([s * 1.0, s * 2.0, 0.0])
    yaw = math.atan2(third.gt_c2w[1, 0], third.gt_c2w[0, 0])
    assert yaw == pytest.approx((1.100 - 1.02) / 0.09 * math.pi / 4, abs=1e-9)  # slerp is linear in angle
    assert first.depth.max() == pytest.approx(1.0)
    assert ds.has_ground_truth and not ds.has_labels


def test_associate_is_one_to_one():
    pairs = associate(np.array([0.0, 0.005, 1.0]), np.array([0.004, 0.5, 1.019]))
    assert pairs == [(1, 0), (2, 2)]


def test_camera_file_overrides_and_options(tum_folder):
    (tum_folder / "camera.yaml").write_text("width: 640\nheight: 480\nfx: 500\nfy: 501\ncx: 319.5\ncy: 239.5\n")
    ds = TumDataset(tum_folder, DatasetOptions(start=1, stride=2, downscale=4))
    assert len(ds) == 2 and ds.intrinsics.width == 160 and ds.intrinsics.fx == pytest.approx(125.0)
    assert ds[0].rgb.shape == (120, 160, 3) and ds[1].stamp_ns == round(1.133e9)
    assert ds[0].depth.max() == pytest.approx(1.0)  # nearest-neighbour keeps metric depth
    assert len(TumDataset(tum_folder, DatasetOptions(max_frames=3))) == 3
    assert len(TumDataset(tum_folder)) == 4


def test_missing_and_corrupt_files_name_the_file(tum_folder):
    (tum_folder / "depth" / "1.005000.png").write_bytes(b"not a png")
    with pytest.raises(DatasetError, match=r"1\.005000\.png"):
        TumDataset(tum_folder)[0]
    (tum_folder / "depth.txt").unlink()
    with pytest.raises(DatasetError, match=r"depth\.txt"):
        TumDataset(tum_folder)


def test_bad_rows_are_reported_with_line_numbers(tum_folder):
    (tum_folder / "groundtruth.txt").write_text("1.0 0 0 0 0 0 1\n")
    with pytest.raises(DatasetError, match=r"groundtruth\.txt:1: expected 8 columns"):
        TumDataset(tum_folder)


@pytest.mark.data
def test_real_tum_teddy_sample(tum_teddy):
    ds = open_dataset(tum_teddy)
    assert isinstance(ds, TumDataset) and ds.intrinsics == TUM_INTRINSICS["fr3"]
    assert 190 <= len(ds) <= 200
    with_gt = [r.gt_c2w is not None for r in ds.records]
    assert not any(with_gt[:5]) and all(with_gt[5:])  # the first 5 frames precede the ground truth
    f = ds[100]
    assert f.rgb.shape == (480, 640, 3) and 0.6 < f.valid_depth_fraction < 0.95
    assert 0.5 < float(np.median(f.depth[f.depth > 0])) < 5.0
    gt = np.stack([r.gt_c2w for r in ds.records if r.gt_c2w is not None])
    steps = np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1)
    assert steps.max() < 0.05  # smooth hand-held motion at 30 Hz
