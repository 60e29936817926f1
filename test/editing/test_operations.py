"""Editing by object: remove, keep, move, rotate, recolour; selection by class, box and instance."""

from __future__ import annotations

from dataclasses import fields

import numpy as np
import pytest
import torch

from sgs_slam_core.editing import (
    EditError,
    EditKind,
    EditRequest,
    Selection,
    apply_edit,
    connected_instances,
    keep_only,
    label_summary,
    move,
    recolor,
    remove,
    select,
)
from sgs_slam_core.gaussians import GaussianMap

from .scene import BOX, BOX_Z, CHAIR, TABLE, WALL, K, draw, labelled_scene


def assert_same(a: GaussianMap, b: GaussianMap) -> None:
    for f in fields(GaussianMap):
        x, y = getattr(a, f.name), getattr(b, f.name)
        assert (x is None and y is None) or torch.equal(x, y), f.name


@pytest.fixture(scope="module")
def scene() -> GaussianMap:
    return labelled_scene()


def test_remove_leaves_no_gaussian_of_the_class_and_the_rest_bit_identical(scene):
    before = scene.clone()
    edited, record = remove(scene, Selection((BOX,)), TABLE)
    assert not bool((edited.labels == BOX).any())
    assert_same(edited, scene.select(scene.labels != BOX))  # every other Gaussian, same bits, same order
    assert_same(scene, before)  # the input is untouched
    assert record.kind is EditKind.REMOVE and record.labels == (BOX,)
    assert record.count == int((scene.labels == BOX).sum()) and record.after == len(scene) - record.count


def test_removed_object_renders_as_the_background_and_nothing_else_changes(scene):
    out, labels = draw(scene)
    box_pixels = labels == BOX
    assert int(box_pixels.sum()) > 50  # the box covers ~18x18 px
    edited, _ = remove(scene, Selection((BOX,)), TABLE)
    out2, labels2 = draw(edited)
    assert int((labels2 == BOX).sum()) == 0
    assert bool((labels2[box_pixels] == WALL).all())  # the wall behind shows through
    only_box, _ = keep_only(scene, Selection((BOX,)), TABLE)
    untouched = draw(only_box)[0].silhouette == 0  # pixels the box never reached
    assert int(untouched.sum()) > 0.7 * untouched.numel()
    torch.testing.assert_close(out2.color[untouched], out.color[untouched], rtol=0, atol=1e-6)
    torch.testing.assert_close(out2.depth[untouched], out.depth[untouched], rtol=0, atol=1e-6)
    assert torch.equal(labels2[untouched], labels[untouched])


def mask_centroid(labels: torch.Tensor, class_id: int) -> np.ndarray:  # [2] (u, v) px
    v, u = torch.nonzero(labels == class_id, as_tuple=True)
    return np.array([u.double().mean().item(), v.double().mean().item()])


@pytest.mark.parametrize("t", [(0.3, 0.0, 0.0), (0.0, -0.2, 0.0), (0.25, 0.15, 0.0)])
def test_moving_shifts_the_rendered_mask_by_the_projected_amount(scene, t):
    before = mask_centroid(draw(scene)[1], BOX)
    edited, record = move(scene, Selection((BOX,)), translation=t, table=TABLE)
    after = mask_centroid(draw(edited)[1], BOX)
    expected = np.array([K.fx * t[0] / BOX_Z, K.fy * t[1] / BOX_Z])  # fronto-parallel box at depth BOX_Z
    np.testing.assert_allclose(after - before, expected, atol=0.35)
    np.testing.assert_allclose(record.transform[:3, 3], t, atol=1e-12)
    assert_same(edited.select(edited.labels != BOX), scene.select(scene.labels != BOX))


def test_moving_away_from_the_camera_shrinks_the_mask_by_the_depth_ratio(scene):
    area = int((draw(scene)[1] == BOX).sum())
    edited, _ = move(scene, Selection((BOX,)), translation=(0.0, 0.0, 0.5), table=TABLE)
    area2 = int((draw(edited)[1] == BOX).sum())
    assert area2 / area == pytest.approx((BOX_Z / (BOX_Z + 0.5)) ** 2, rel=0.12)


@pytest.mark.parametrize("rotation", [(360.0, 0.0, 0.0), (0.0, 360.0, 0.0), (0.0, 0.0, -360.0), (360.0, 360.0, 360.0)])
def test_rotating_by_360_degrees_is_the_identity(scene, rotation):
    edited, record = move(scene, Selection((BOX,)), rotation_deg=rotation, table=TABLE)
    torch.testing.assert_close(edited.means, scene.means, rtol=0, atol=1e-6)
    np.testing.assert_allclose(record.transform, np.eye(4), atol=1e-12)


def test_four_quarter_turns_about_the_centroid_return_the_object(scene):
    edited = scene
    for _ in range(4):
        edited, record = move(edited, Selection((BOX,)), rotation_deg=(0.0, 0.0, 90.0), table=TABLE)
    torch.testing.assert_close(edited.means, scene.means, rtol=0, atol=1e-5)
    np.testing.assert_allclose(record.pivot, [0.0, 0.0, BOX_Z], atol=1e-6)


def test_rotation_about_the_centroid_keeps_the_centroid_and_turns_the_extent(scene):
    edited, _ = move(scene, Selection((CHAIR,), instance=0), rotation_deg=(0.0, 0.0, 90.0), table=TABLE)
    sel = select(scene, Selection((CHAIR,), instance=0), TABLE)
    before, after = scene.means[sel].double(), edited.means[sel].double()
    torch.testing.assert_close(after.mean(0), before.mean(0), rtol=0, atol=1e-6)
    extent_before = before.amax(0) - before.amin(0)
    extent_after = after.amax(0) - after.amin(0)
    torch.testing.assert_close(extent_after[[1, 0]], extent_before[[0, 1]], rtol=0, atol=1e-5)


def test_rotation_about_a_given_point(scene):
    edited, _ = move(scene, Selection((BOX,)), rotation_deg=(0.0, 180.0, 0.0), pivot=(0.0, 0.0, 2.5), table=TABLE)
    box = edited.means[edited.labels == BOX]
    torch.testing.assert_close(
        box[:, 2], torch.full_like(box[:, 2], 3.0), rtol=0, atol=1e-5
    )  # mirrored behind the pivot


def test_anisotropic_gaussians_are_rotated_too(scene):
    aniso = scene.with_tensors(
        log_scales=scene.log_scales.expand(-1, 3).clone(),
        quats=torch.tensor([1.0, 0.0, 0.0, 0.0]).expand(len(scene), 4).clone(),
    )
    edited, _ = move(aniso, Selection((BOX,)), rotation_deg=(0.0, 0.0, 90.0), table=TABLE)
    q = edited.quats[edited.labels == BOX][0]
    half = np.sqrt(0.5)
    torch.testing.assert_close(q, torch.tensor([half, 0.0, 0.0, half], dtype=torch.float32), rtol=0, atol=1e-6)
    assert torch.equal(edited.quats[edited.labels != BOX], aniso.quats[aniso.labels != BOX])


def test_select_by_name_and_several_classes(scene):
    by_name = select(scene, Selection((TABLE.name_of(BOX), TABLE.name_of(CHAIR))), TABLE)
    by_id = select(scene, Selection((BOX, CHAIR)), TABLE)
    assert torch.equal(by_name, by_id)
    assert int(by_id.sum()) == int(((scene.labels == BOX) | (scene.labels == CHAIR)).sum())


def test_instances_split_two_objects_of_one_class(scene):
    chairs = scene.labels == CHAIR
    big = select(scene, Selection((CHAIR,), instance=0), TABLE)
    small = select(scene, Selection((CHAIR,), instance=1), TABLE)
    assert int(big.sum()) > int(small.sum()) > 0
    assert torch.equal(big | small, chairs) and not bool((big & small).any())
    assert float(scene.means[big, 0].max()) < 0 < float(scene.means[small, 0].min())  # left and right
    with pytest.raises(EditError, match="2 instances"):
        select(scene, Selection((CHAIR,), instance=2), TABLE)


def test_a_box_limits_the_selection(scene):
    right = select(scene, Selection((CHAIR,), box=((0.0, -5.0, 0.0), (5.0, 5.0, 5.0))), TABLE)
    assert torch.equal(right, select(scene, Selection((CHAIR,), instance=1), TABLE))
    with pytest.raises(EditError, match="in the box"):
        select(scene, Selection((BOX,), box=((5.0, 5.0, 5.0), (6.0, 6.0, 6.0))), TABLE)


def test_connected_instances_link_distance():
    line = np.array([[0.0, 0, 0], [0.04, 0, 0], [0.08, 0, 0], [1.0, 0, 0], [1.04, 0, 0]])
    np.testing.assert_array_equal(connected_instances(line, 0.05), [0, 0, 0, 1, 1])
    np.testing.assert_array_equal(connected_instances(line, 2.0), [0, 0, 0, 0, 0])
    assert connected_instances(np.zeros((0, 3)), 0.05).shape == (0,)


def test_keep_only_and_recolor(scene):
    kept, record = keep_only(scene, Selection((BOX,)), TABLE)
    assert set(kept.labels.tolist()) == {BOX} and record.count == len(scene) - len(kept)
    painted, _ = recolor(scene, Selection((BOX,)), (0.0, 1.0, 0.0), TABLE)
    assert torch.equal(painted.colors[painted.labels == BOX][0], torch.tensor([0.0, 1.0, 0.0]))
    assert torch.equal(painted.colors[painted.labels != BOX], scene.colors[scene.labels != BOX])
    with pytest.raises(EditError, match=r"\[0, 1\]"):
        recolor(scene, Selection((BOX,)), (2.0, 0.0, 0.0), TABLE)


def test_apply_edit_dispatches_requests(scene):
    moved, record = apply_edit(scene, EditRequest(EditKind.MOVE, Selection((BOX,)), translation=(0.0, 0.0, 1.0)), TABLE)
    assert record.kind is EditKind.MOVE and "move" in record.summary()
    assert float(moved.means[moved.labels == BOX, 2].min()) == pytest.approx(BOX_Z + 1.0)
    with pytest.raises(EditError, match="rgb"):
        EditRequest(EditKind.RECOLOR, Selection((BOX,)))


@pytest.mark.parametrize(
    ("selection", "message"),
    [
        (lambda: Selection(("no-such-class",)), "no-such-class"),
        (lambda: Selection((39,)), "no Gaussian matches class 39"),
        (lambda: Selection(()), "at least one class"),
        (lambda: Selection((BOX,), instance=-1), "instance"),
    ],
)
def test_bad_selections_raise_edit_errors(scene, selection, message):
    with pytest.raises(EditError, match=message):
        select(scene, selection(), TABLE)


def test_label_summary_counts_and_bounds(scene):
    rows = {row[0]: row for row in label_summary(scene, TABLE)}
    assert set(rows) == {WALL, BOX, CHAIR}
    _, name, count, lo, hi = rows[BOX]
    assert name == TABLE.name_of(BOX) and count == int((scene.labels == BOX).sum())
    np.testing.assert_allclose(lo, [-0.3, -0.3, BOX_Z], atol=1e-5)
    np.testing.assert_allclose(hi, [0.3, 0.3, BOX_Z], atol=1e-5)
