"""Native map files and PLY exports: exact round trips, atomic writes, errors that name the problem."""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest
import torch

from sgs_slam_core.errors import MapFileError, OutputError
from sgs_slam_core.fileio import atomic_write
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.labels import LabelTable
from sgs_slam_core.mapio import (
    MapFile,
    load_map,
    read_splat_ply,
    save_map,
    write_map_point_cloud,
    write_splat_ply,
)

from ..editing.scene import BOX, labelled_scene


def random_map(n: int, s: int, anisotropic: bool, seed: int = 0) -> GaussianMap:
    g = torch.Generator().manual_seed(seed)
    return GaussianMap(
        means=torch.randn(n, 3, generator=g),
        log_scales=torch.randn(n, 3 if anisotropic else 1, generator=g) - 4,
        logit_opacities=torch.randn(n, generator=g),
        colors=torch.rand(n, 3, generator=g) * 1.2 - 0.1,  # not clamped while optimising
        semantics=torch.rand(n, s, generator=g),
        labels=torch.randint(0, 40, (n,), generator=g),
        birth_frame=torch.randint(0, 1000, (n,), generator=g),
        quats=torch.nn.functional.normalize(torch.randn(n, 4, generator=g), dim=1) if anisotropic else None,
    )


def assert_same(a: GaussianMap, b: GaussianMap) -> None:
    for f in fields(GaussianMap):
        x, y = getattr(a, f.name), getattr(b, f.name)
        assert (x is None and y is None) or (x.dtype == y.dtype and torch.equal(x, y)), f.name


def map_file(gaussians: GaussianMap) -> MapFile:
    poses = [np.eye(4) + 0.01 * i for i in range(3)]
    return MapFile(
        gaussians,
        LabelTable.nyu40(),
        {"semantic": {"mode": "color"}, "seed": 3},
        Intrinsics(500.0, 501.0, 319.5, 239.5, 640, 480),
        [(0, poses[0]), (5, poses[1])],
        [(i, 1_000 * i, p) for i, p in enumerate(poses)],
        [0, 1, 5],
        4.5,
        [5],
        frames_processed=7,
    )


@pytest.mark.parametrize(("s", "anisotropic"), [(3, False), (41, False), (3, True)])
def test_native_round_trip_is_exact(tmp_path, s, anisotropic):
    original = map_file(random_map(500, s, anisotropic))
    save_map(tmp_path / "m.sgsmap", original)
    loaded = load_map(tmp_path / "m.sgsmap")
    assert_same(loaded.gaussians, original.gaussians)
    assert loaded.label_table == original.label_table and loaded.config == original.config
    assert loaded.intrinsics == original.intrinsics and loaded.scene_radius == 4.5
    assert loaded.seen_labels == [0, 1, 5] and loaded.locked_labels == [5] and loaded.frames_processed == 7
    for (i, p), (j, q) in zip(loaded.keyframes, original.keyframes, strict=True):
        assert i == j and np.array_equal(p, q)
    for (i, t, p), (j, u, q) in zip(loaded.trajectory, original.trajectory, strict=True):
        assert (i, t) == (j, u) and np.array_equal(p, q)


@pytest.mark.parametrize(("s", "anisotropic"), [(3, False), (41, False), (3, True)])
def test_splat_ply_round_trip_is_exact(tmp_path, s, anisotropic):
    original = random_map(300, s, anisotropic)
    table = LabelTable.nyu40()
    write_splat_ply(tmp_path / "m.ply", original, table)
    loaded, loaded_table = read_splat_ply(tmp_path / "m.ply")
    assert_same(loaded, original)
    assert loaded_table == table


def header(path: Path) -> list[str]:
    raw = path.read_bytes()
    return raw[: raw.index(b"end_header")].decode("ascii").splitlines()


def test_splat_ply_has_the_standard_3dgs_layout(tmp_path):
    write_splat_ply(tmp_path / "m.ply", random_map(10, 3, False))
    lines = header(tmp_path / "m.ply")
    assert lines[:2] == ["ply", "format binary_little_endian 1.0"]
    assert "element vertex 10" in lines
    props = [line.split()[-1] for line in lines if line.startswith("property")]
    standard = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity",
                "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]  # fmt: skip
    assert props[: len(standard)] == standard and "label" in props
    assert all(line.split()[1] == "float" for line in lines if line.split()[-1] in standard)


def test_a_foreign_3dgs_ply_imports_without_semantics(tmp_path):
    """A PLY from another 3DGS tool: SH colour, no labels, anisotropic."""
    n = 4
    names = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
             "rot_0", "rot_1", "rot_2", "rot_3"]  # fmt: skip
    data = np.zeros(n, dtype=[(k, "<f4") for k in names])
    data["f_dc_0"] = (0.75 - 0.5) / 0.28209479177387814
    data["rot_0"] = 1.0
    head = ["ply", "format binary_little_endian 1.0", f"element vertex {n}", *(f"property float {k}" for k in names)]
    (tmp_path / "other.ply").write_bytes(("\n".join([*head, "end_header"]) + "\n").encode() + data.tobytes())
    g, table = read_splat_ply(tmp_path / "other.ply")
    assert table is None and not g.isotropic and g.num_semantic == 0 and len(g) == n
    torch.testing.assert_close(g.colors[:, 0], torch.full((n,), 0.75))
    assert bool((g.labels == 0).all())


def test_point_cloud_ply_in_colour_and_semantic_colour(tmp_path):
    scene = labelled_scene()
    table = LabelTable.nyu40()
    n = write_map_point_cloud(tmp_path / "rgb.ply", scene, table)
    m = write_map_point_cloud(tmp_path / "sem.ply", scene, table, semantic=True)
    assert n == m == len(scene)  # every Gaussian of the scene is opaque
    lines = header(tmp_path / "sem.ply")
    props = [line.split()[-1] for line in lines if line.startswith("property")]
    assert props == ["x", "y", "z", "red", "green", "blue", "label"] and f"element vertex {n}" in lines
    raw = (tmp_path / "sem.ply").read_bytes()
    body = raw[raw.index(b"end_header\n") + len(b"end_header\n") :]
    dtype = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("r", "u1"), ("g", "u1"), ("b", "u1"), ("l", "<i4")])
    pts = np.frombuffer(body, dtype=dtype)
    box = pts[pts["l"] == BOX]
    assert len(box) == int((scene.labels == BOX).sum())
    for channel, value in zip("rgb", table.color_of(BOX), strict=True):
        assert bool(np.all(box[channel] == value))
    assert int(np.abs(box["z"] - 2.0).max() * 1e6) == 0


def test_truncated_map_file_is_named_and_a_failed_write_keeps_the_previous_file(tmp_path):
    path = tmp_path / "m.sgsmap"
    first = map_file(random_map(200, 3, False, seed=1))
    save_map(path, first)
    good = path.read_bytes()

    def crash_midway(f):
        f.write(good[: len(good) // 2])
        raise OSError("disk full")

    with pytest.raises(OutputError, match=f"cannot write {path}: disk full"):
        atomic_write(path, crash_midway)
    assert path.read_bytes() == good  # the previous file survives
    assert not [p for p in tmp_path.iterdir() if p.name != "m.sgsmap"]  # no temp file left behind
    assert_same(load_map(path).gaussians, first.gaussians)

    cut = tmp_path / "cut.sgsmap"
    cut.write_bytes(good[: len(good) // 2])
    with pytest.raises(MapFileError, match="truncated"):
        load_map(cut)


def test_truncated_ply_is_named(tmp_path):
    write_splat_ply(tmp_path / "m.ply", random_map(50, 3, False))
    raw = (tmp_path / "m.ply").read_bytes()
    (tmp_path / "m.ply").write_bytes(raw[:-100])
    with pytest.raises(MapFileError, match="truncated"):
        read_splat_ply(tmp_path / "m.ply")


def edited_payload(path: Path, change) -> None:
    data = torch.load(path, weights_only=True)
    change(data)
    torch.save(data, path)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda d: d.update(version=99), "version 99 is not supported"),
        (lambda d: d.pop("trajectory"), r"missing fields \['trajectory'\]"),
        (lambda d: d.update(format="x"), "not an SGS-SLAM map"),
        (lambda d: d["gaussians"].pop("colors"), r"missing \['colors'\]"),
        (lambda d: d["gaussians"].update(colors=torch.zeros(3, 3)), "colors"),
        (lambda d: d.update(keyframes=[[0, torch.eye(3, dtype=torch.float64)]]), "4x4"),
    ],
)
def test_invalid_map_files_name_what_is_wrong(tmp_path, change, message):
    path = tmp_path / "m.sgsmap"
    save_map(path, map_file(random_map(20, 3, False)))
    edited_payload(path, change)
    with pytest.raises(MapFileError, match=message):
        load_map(path)


def test_missing_file_and_non_map(tmp_path):
    with pytest.raises(MapFileError, match="does not exist"):
        load_map(tmp_path / "none.sgsmap")
    (tmp_path / "junk.sgsmap").write_bytes(b"not a zip")
    with pytest.raises(MapFileError):
        load_map(tmp_path / "junk.sgsmap")
