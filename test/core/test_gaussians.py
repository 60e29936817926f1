import math

import pytest
import torch

from sgs_slam_core.errors import ShapeError
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.geometry import se3_from_rt, so3_exp


def make_map(n: int = 10, s: int = 3, anisotropic: bool = False) -> GaussianMap:
    g = torch.Generator().manual_seed(0)
    return GaussianMap(
        means=torch.randn(n, 3, generator=g),
        log_scales=torch.randn(n, 3 if anisotropic else 1, generator=g),
        logit_opacities=torch.randn(n, generator=g),
        colors=torch.rand(n, 3, generator=g),
        semantics=torch.rand(n, s, generator=g),
        labels=torch.arange(n) % 3,
        birth_frame=torch.zeros(n, dtype=torch.long),
        quats=torch.nn.functional.normalize(torch.randn(n, 4, generator=g), dim=1) if anisotropic else None,
    )


def test_validation_names_the_bad_field():
    m = make_map()
    with pytest.raises(ShapeError, match="colors"):
        m.with_tensors(colors=torch.zeros(9, 3))
    with pytest.raises(ShapeError, match="labels must be int64"):
        m.with_tensors(labels=torch.zeros(10, dtype=torch.int32))
    with pytest.raises(ShapeError, match="log_scales"):
        m.with_tensors(log_scales=torch.zeros(10, 3))


def test_cat_select_prune():
    a, b = make_map(10), make_map(4)
    both = a.cat(b)
    assert len(both) == 14 and torch.equal(both.means[10:], b.means)
    keep = a.labels == 1
    sub = a.select(keep)
    assert len(sub) == int(keep.sum()) and bool((sub.labels == 1).all())
    by_index = a.select(keep.nonzero().squeeze(1))  # the same rows, each field gathered as the mask indexes it
    assert all(torch.equal(getattr(sub, f), getattr(by_index, f)) for f in ("means", "colors", "semantics", "labels"))
    assert torch.equal(sub.means, a.means[keep]) and len(a.select(keep[:0].nonzero().squeeze(1))) == 0
    pruned = a.prune(keep)
    assert len(pruned) == 10 - len(sub) and not bool((pruned.labels == 1).any())
    with pytest.raises(ShapeError, match="cannot join"):
        a.cat(make_map(3, s=5))
    with pytest.raises(ShapeError):
        a.prune(torch.zeros(10, dtype=torch.long))


def test_transform_subset_leaves_the_rest_and_the_original_untouched():
    m = make_map(10, anisotropic=True)
    before = m.means.clone()
    pose = se3_from_rt(so3_exp(torch.tensor([0.0, 0.0, math.pi / 2])), torch.tensor([1.0, 0.0, 0.0]))
    mask = m.labels == 2
    moved = m.transformed(pose, mask)
    assert torch.equal(m.means, before)
    assert torch.equal(moved.means[~mask], m.means[~mask])
    expected = m.means[mask] @ pose[:3, :3].T + pose[:3, 3]
    assert torch.allclose(moved.means[mask], expected, atol=1e-6)
    assert torch.equal(moved.quats[~mask], m.quats[~mask])
    assert not torch.allclose(moved.quats[mask], m.quats[mask])


def test_state_dict_round_trip_and_errors():
    m = make_map(6, anisotropic=True)
    back = GaussianMap.from_state_dict(m.state_dict())
    for name, tensor in m.state_dict().items():
        assert torch.equal(getattr(back, name), tensor)
    state = m.state_dict()
    del state["colors"]
    with pytest.raises(ShapeError, match="missing"):
        GaussianMap.from_state_dict(state)


def test_empty_and_activations():
    e = GaussianMap.empty(5)
    assert len(e) == 0 and e.num_semantic == 5 and e.isotropic
    m = make_map(4)
    assert torch.allclose(m.opacities, torch.sigmoid(m.logit_opacities))
    assert torch.allclose(m.scales, torch.exp(m.log_scales))
