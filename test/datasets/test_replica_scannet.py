import cv2
import numpy as np
import pytest
import yaml

from sgs_slam_core.datasets import DatasetOptions, ReplicaDataset, ScanNetDataset, detect_format, open_dataset
from sgs_slam_core.datasets.replica import REPLICA_INTRINSICS
from sgs_slam_core.errors import DatasetError
from sgs_slam_core.labels import LabelTable


def write_traj(path, n, offset=0.0):
    poses = []
    for i in range(n):
        p = np.eye(4)
        p[0, 3] = 0.01 * i + offset
        poses.append(p.reshape(-1))
    np.savetxt(path, np.stack(poses))


def test_replica_nice_slam_layout_with_default_camera(tmp_path):
    root = tmp_path / "room0"
    (root / "results").mkdir(parents=True)
    for i in range(3):
        cv2.imwrite(str(root / "results" / f"frame{i:06d}.jpg"), np.full((680, 1200, 3), 90, np.uint8))
        cv2.imwrite(str(root / "results" / f"depth{i:06d}.png"), np.full((680, 1200), 13107, np.uint16))
    write_traj(root / "traj.txt", 3)
    assert detect_format(root) == "replica"
    ds = open_dataset(root, options=DatasetOptions(downscale=4))
    assert ds.layout == "nice-slam" and not ds.has_labels and ds.has_ground_truth
    assert ds.intrinsics == REPLICA_INTRINSICS.scaled(0.25)
    f = ds[2]
    assert f.depth.shape == (170, 300) and f.depth.max() == pytest.approx(2.0)  # 13107 / 6553.5
    assert f.gt_c2w[0, 3] == pytest.approx(0.02)


def sgs_layout(root, n=3, size=(16, 12), ids=(0, 3, 7)):
    for sub in ("frames", "depths", "semantic_ids", "semantic_colors"):
        (root / sub).mkdir(parents=True)
    w, h = size
    lab = np.zeros((h, w), np.uint16)
    lab[:, 4:8], lab[:, 8:] = ids[1], ids[2]
    colors = {ids[0]: (0, 0, 0), ids[1]: (10, 20, 30), ids[2]: (200, 100, 50)}
    color_img = np.zeros((h, w, 3), np.uint8)
    for i, c in colors.items():
        color_img[lab == i] = c
    for i in range(n):
        cv2.imwrite(str(root / "frames" / f"frame{i:06d}.jpg"), np.full((h, w, 3), 60, np.uint8))
        cv2.imwrite(str(root / "depths" / f"depth{i:06d}.png"), np.full((h, w), 6554, np.uint16))
        cv2.imwrite(str(root / "semantic_ids" / f"semantic_id{i:06d}.png"), lab)
        cv2.imwrite(str(root / "semantic_colors" / f"semantic_color{i:06d}.png"), color_img[..., ::-1])
    write_traj(root / "traj.txt", n)
    (root / "camera.yaml").write_text(
        f"width: {w}\nheight: {h}\nfx: 10\nfy: 10\ncx: 7.5\ncy: 5.5\ndepth_scale: 6553.5\n"
    )
    return lab


def test_replica_sgs_layout_reads_labels_and_dataset_colours(tmp_path):
    lab = sgs_layout(tmp_path / "s")
    ds = ReplicaDataset(tmp_path / "s")
    assert ds.layout == "sgs-slam" and ds.has_labels
    f = ds[1]
    assert np.array_equal(f.labels, lab) and f.labels.dtype == np.int32
    assert ds.label_table.color_of(3) == (10, 20, 30) and ds.label_table.color_of(7) == (200, 100, 50)
    # labels.yaml wins over colours sampled from the images
    (tmp_path / "s" / "labels.yaml").write_text(yaml.safe_dump(LabelTable.nyu40().to_dict()))
    assert ReplicaDataset(tmp_path / "s").label_table == LabelTable.nyu40()


def test_replica_errors(tmp_path):
    sgs_layout(tmp_path / "s")
    write_traj(tmp_path / "s" / "traj.txt", 2)
    with pytest.raises(DatasetError, match="2 poses for 3 frames"):
        ReplicaDataset(tmp_path / "s")
    (tmp_path / "s" / "traj.txt").write_text("1 2 3\n")
    with pytest.raises(DatasetError, match=r"traj\.txt:1: expected 16 numbers"):
        ReplicaDataset(tmp_path / "s")
    with pytest.raises(DatasetError, match="not a Replica folder"):
        ReplicaDataset(tmp_path)
    with pytest.raises(DatasetError, match="cannot tell the format"):
        open_dataset(tmp_path)


@pytest.fixture
def scannet_scene(tmp_path):
    root = tmp_path / "scans" / "scene0000_00"
    for sub in ("color", "depth", "pose", "intrinsic", "label-filt"):
        (root / sub).mkdir(parents=True)
    k = np.eye(4)
    k[0, 0], k[1, 1], k[0, 2], k[1, 2] = 1169.62, 1167.11, 646.30, 489.93
    np.savetxt(root / "intrinsic" / "intrinsic_color.txt", k)
    np.savetxt(root / "intrinsic" / "intrinsic_depth.txt", np.eye(4))
    raw = np.zeros((968, 1296), np.uint16)
    raw[:, :400] = 1  # raw id 1 -> wall (1)
    raw[:, 400:800] = 1163  # a raw id above 255 -> chair (5)
    raw[:, 800:] = 999  # not in the mapping -> 0
    for i in range(4):
        cv2.imwrite(str(root / "color" / f"{i}.jpg"), np.full((968, 1296, 3), 128, np.uint8))
        cv2.imwrite(str(root / "depth" / f"{i}.png"), np.full((480, 640), 1500, np.uint16))
        cv2.imwrite(str(root / "label-filt" / f"{i}.png"), raw)
        pose = np.eye(4)
        pose[2, 3] = i
        if i == 2:
            pose[0, 0] = -np.inf  # ScanNet marks lost tracking this way
        np.savetxt(root / "pose" / f"{i}.txt", pose)
    (tmp_path / "scans" / "scannetv2-labels.combined.tsv").write_text(
        "id\traw_category\tcategory\tcount\tnyu40id\tnyu40class\n1\twall\twall\t10\t1\twall\n"
        "1163\tdesk chair\tchair\t3\t5\tchair\n40\tthing\tthing\t1\t\t\n"
    )
    return root


def test_scannet_registration_mapping_and_skipped_poses(scannet_scene):
    assert detect_format(scannet_scene) == "scannet"
    ds = ScanNetDataset(scannet_scene)
    assert ds.skipped == 1 and len(ds) == 3
    assert [r.gt_c2w[2, 3] for r in ds.records] == [0, 1, 3]
    k = ds.intrinsics
    assert (k.width, k.height) == (640, 480)
    assert k.fx == pytest.approx(1169.62 * 640 / 1296) and k.fy == pytest.approx(1167.11 * 480 / 968)
    f = ds[1]
    assert f.rgb.shape == (480, 640, 3) and f.depth.max() == pytest.approx(1.5)
    assert set(np.unique(f.labels)) == {0, 1, 5}
    assert (f.labels[:, :190] == 1).all() and (f.labels[:, 200:390] == 5).all() and (f.labels[:, 400:] == 0).all()
    assert ds.label_table.name_of(5) == "chair"


def test_scannet_needs_the_mapping_for_labels(scannet_scene):
    (scannet_scene.parent / "scannetv2-labels.combined.tsv").unlink()
    with pytest.raises(DatasetError, match=r"scannetv2-labels\.combined\.tsv"):
        ScanNetDataset(scannet_scene)
    with pytest.raises(DatasetError, match="not found"):
        ScanNetDataset(scannet_scene, label_tsv=scannet_scene / "nope.tsv")


def test_unknown_format_is_rejected(tmp_path):
    with pytest.raises(DatasetError, match="unknown dataset format 'kitti'"):
        open_dataset(tmp_path, "kitti")
    with pytest.raises(DatasetError, match="does not exist"):
        open_dataset(tmp_path / "missing")
