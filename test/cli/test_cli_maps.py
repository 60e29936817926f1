"""``sgs-slam edit | render | labels | export`` on a saved labelled map."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import torch

from sgs_slam_core.cli import main
from sgs_slam_core.mapio import MapFile, load_map, read_splat_ply, save_map
from sgs_slam_core.metrics.trajectory_io import write_tum_trajectory

from ..editing.scene import BOX, CHAIR, TABLE, WALL, K, labelled_scene


@pytest.fixture
def map_path(tmp_path):
    path = tmp_path / "scene.sgsmap"
    save_map(path, MapFile(labelled_scene(), TABLE, {}, K, [(0, np.eye(4))], [(0, 0, np.eye(4))], [0, 1, 5, 6]))
    return path


def test_labels_lists_classes_counts_and_boxes(map_path, capsys):
    assert main(["labels", str(map_path)]) == 0
    text = capsys.readouterr().out
    assert TABLE.name_of(BOX) in text and TABLE.name_of(CHAIR) in text
    assert main(["labels", str(map_path), "--json"]) == 0
    rows = {r["id"]: r for r in json.loads(capsys.readouterr().out)}
    scene = labelled_scene()
    assert set(rows) == {WALL, BOX, CHAIR}
    assert rows[BOX]["gaussians"] == int((scene.labels == BOX).sum())
    assert rows[BOX]["bbox_min_m"] == [-0.3, -0.3, 2.0] and not rows[BOX]["locked"]


def test_edit_remove_writes_a_new_locked_map_and_leaves_the_input(map_path, tmp_path, capsys):
    before = map_path.read_bytes()
    out = tmp_path / "no_box.sgsmap"
    assert main(["edit", str(map_path), "--remove-label", TABLE.name_of(BOX), "--out", str(out)]) == 0
    assert "removed" in capsys.readouterr().out
    edited = load_map(out)
    assert not bool((edited.gaussians.labels == BOX).any()) and edited.locked_labels == [BOX]
    assert edited.trajectory[0][2].shape == (4, 4) and edited.intrinsics == K  # context carried over
    assert map_path.read_bytes() == before
    assert main(["labels", str(out)]) == 0 and "locked" not in capsys.readouterr().out.split(TABLE.name_of(WALL))[0]


def test_edit_move_one_instance_to_ply(map_path, tmp_path):
    out = tmp_path / "moved.ply"
    args = [
        "edit",
        str(map_path),
        "--move-label",
        str(CHAIR),
        "--instance",
        "1",
        "--translate",
        "0",
        "0.5",
        "0",
        "--rotate-deg",
        "0",
        "0",
        "360",
        "--out",
        str(out),
    ]
    assert main(args) == 0
    moved, table = read_splat_ply(out)
    scene = labelled_scene()
    small = (scene.labels == CHAIR) & (scene.means[:, 0] > 0)
    torch.testing.assert_close(
        moved.means[small] - scene.means[small],
        torch.tensor([[0.0, 0.5, 0.0]]).expand(int(small.sum()), 3),
        rtol=0,
        atol=1e-5,
    )
    assert torch.equal(moved.means[~small], scene.means[~small]) and table == TABLE


def test_render_views_from_a_matrix_a_trajectory_and_an_orbit(map_path, tmp_path, capsys):
    c2w = tmp_path / "c2w.txt"
    np.savetxt(c2w, np.eye(4))
    assert main(["render", str(map_path), "--c2w", str(c2w), "--out", str(tmp_path / "one"), "--semantic"]) == 0
    sem = cv2.imread(str(tmp_path / "one" / "semantic_00000.png"))[..., ::-1]
    assert sem.shape == (K.height, K.width, 3)
    assert np.all(sem[K.height // 2, K.width // 2] == TABLE.color_of(BOX))  # the box in the middle
    ids = cv2.imread(str(tmp_path / "one" / "labels_00000.png"), cv2.IMREAD_UNCHANGED)
    assert ids.dtype == np.uint16 and ids[K.height // 2, K.width // 2] == BOX  # the class id, for any scorer
    depth = cv2.imread(str(tmp_path / "one" / "depth_00000.png"), cv2.IMREAD_UNCHANGED)
    assert depth.dtype == np.uint16 and abs(int(depth[K.height // 2, K.width // 2]) - 2000) < 30  # mm

    traj = tmp_path / "traj.txt"
    write_tum_trajectory(traj, [0, 1_000_000_000], np.stack([np.eye(4), np.eye(4)]))
    assert (
        main(["render", str(map_path), "--trajectory", str(traj), "--out", str(tmp_path / "tr"), "--width", "32"]) == 0
    )
    assert cv2.imread(str(tmp_path / "tr" / "color_00001.png")).shape == (24, 32, 3)

    assert main(["render", str(map_path), "--orbit", "3", "--out", str(tmp_path / "orbit")]) == 0
    assert sorted(p.name for p in (tmp_path / "orbit").iterdir()) == [
        f"{kind}_{i:05d}.png" for kind in ("color", "depth") for i in range(3)
    ]
    assert "rendered 3 views" in capsys.readouterr().out


def test_export_splat_and_point_clouds(map_path, tmp_path):
    assert main(["export", str(map_path), "--out", str(tmp_path / "s.ply")]) == 0
    assert len(read_splat_ply(tmp_path / "s.ply")[0]) == len(labelled_scene())
    assert main(["export", str(map_path), "--out", str(tmp_path / "p.ply"), "--points", "--semantic"]) == 0
    assert b"property uchar red" in (tmp_path / "p.ply").read_bytes()[:400]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["edit", "{map}", "--remove-label", "bed", "--out", "{tmp}/x.sgsmap"], "no Gaussian matches class 4"),
        (["edit", "{map}", "--remove-label", "wardrobe", "--out", "{tmp}/x.sgsmap"], "wardrobe"),
        (
            ["edit", "{map}", "--remove-label", "5", "--translate", "1", "0", "0", "--out", "{tmp}/x.sgsmap"],
            "go with --move-label",
        ),
        (["edit", "{map}", "--remove-label", "5", "--out", "{tmp}/x.txt"], "map files end in"),
        (["edit", "{map}", "--remove-label", "5", "--out", "{map}"], "exists"),
        (["edit", "{tmp}/none.sgsmap", "--remove-label", "5", "--out", "{tmp}/x.sgsmap"], "does not exist"),
        (["render", "{map}", "--c2w", "{tmp}/bad.txt", "--out", "{tmp}/r"], "expected 16 numbers"),
        (["labels", "{tmp}/trunc.sgsmap"], "truncated"),
        (["export", "{map}", "--out", "{tmp}/x.ply", "--semantic"], "add --points"),
    ],
)
def test_bad_input_is_one_line_and_exit_1(args, message, map_path, tmp_path, capsys):
    (tmp_path / "bad.txt").write_text("1 0 0\n0 1 0\n")
    (tmp_path / "trunc.sgsmap").write_bytes(map_path.read_bytes()[:3000])
    args = [a.format(map=map_path, tmp=tmp_path) for a in args]
    assert main(args) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err and err.startswith("sgs-slam: error:"), err
