import pytest
import torch

from sgs_slam_core.errors import ShapeError
from sgs_slam_core.geometry import Intrinsics, backproject


def test_intrinsics_validation():
    with pytest.raises(ShapeError, match="positive"):
        Intrinsics(0.0, 500.0, 10.0, 10.0, 20, 20)
    with pytest.raises(ShapeError, match="finite"):
        Intrinsics(float("nan"), 500.0, 10.0, 10.0, 20, 20)
    with pytest.raises(ShapeError, match="image size"):
        Intrinsics(500.0, 500.0, 10.0, 10.0, 0, 20)


def test_scaled_keeps_the_image_centre_and_field_of_view():
    k = Intrinsics(600.0, 600.0, 599.5, 339.5, 1200, 680)
    half = k.scaled(0.5)
    assert (half.width, half.height) == (600, 340)
    assert half.fx == pytest.approx(300.0)
    assert half.cx == pytest.approx((half.width - 1) / 2)
    assert half.cy == pytest.approx((half.height - 1) / 2)
    # The angle of a pixel edge is preserved: (0 - 0.5 - cx) / fx.
    assert (-0.5 - half.cx) / half.fx == pytest.approx((-0.5 - k.cx) / k.fx)
    with pytest.raises(ShapeError):
        k.scaled(0.0)


def test_backproject_reprojects_to_the_same_pixels():
    k = Intrinsics(50.0, 60.0, 15.5, 11.0, 32, 24)
    depth = torch.rand(24, 32) * 3 + 0.5
    depth[0, 0] = 0.0
    pts, mask = backproject(depth, k)
    assert int(mask.sum()) == 32 * 24 - 1
    u = pts[:, 0] / pts[:, 2] * k.fx + k.cx
    v = pts[:, 1] / pts[:, 2] * k.fy + k.cy
    vv, uu = torch.nonzero(mask, as_tuple=True)
    assert torch.allclose(u, uu.float(), atol=1e-4)
    assert torch.allclose(v, vv.float(), atol=1e-4)
    c2w = torch.eye(4)
    c2w[:3, 3] = torch.tensor([1.0, 2.0, 3.0])
    world, _ = backproject(depth, k, c2w)
    assert torch.allclose(world - pts, torch.tensor([1.0, 2.0, 3.0]).expand_as(pts))
    with pytest.raises(ShapeError, match="depth is"):
        backproject(torch.ones(5, 5), k)
