import math

import numpy as np
import pytest
import torch

from sgs_slam_core.errors import ShapeError
from sgs_slam_core.metrics import ConfusionMatrix, depth_l1, load_lpips, ms_ssim, paper_frame_miou, psnr, ssim
from sgs_slam_core.metrics.lpips import Lpips


def image(seed=0, h=64, w=80):
    return torch.rand(h, w, 3, generator=torch.Generator().manual_seed(seed))


def test_psnr_known_values():
    gt = torch.full((10, 10, 3), 0.5)
    assert psnr(gt + 0.1, gt) == pytest.approx(20.0, abs=1e-4)  # MSE 0.01
    assert psnr(gt + 0.01, gt) == pytest.approx(40.0, abs=1e-3)
    assert math.isinf(psnr(gt, gt))
    mask = torch.zeros(10, 10, dtype=torch.bool)
    mask[:5] = True
    pred = gt.clone()
    pred[5:] += 0.3  # errors only outside the mask
    assert math.isinf(psnr(pred, gt, mask)) and psnr(pred, gt) < 20
    with pytest.raises(ShapeError):
        psnr(gt, gt[:5])


def test_ssim_properties():
    a = image(0)
    assert ssim(a, a).item() == pytest.approx(1.0, abs=1e-6)
    noisy = (a + 0.05 * torch.randn(a.shape, generator=torch.Generator().manual_seed(1))).clamp(0, 1)
    very = (a + 0.2 * torch.randn(a.shape, generator=torch.Generator().manual_seed(1))).clamp(0, 1)
    assert 1 > ssim(noisy, a).item() > ssim(very, a).item() > 0
    assert ssim(noisy, a).item() == pytest.approx(ssim(a, noisy).item(), abs=1e-6)
    same = ssim(noisy, a, padding="same")
    assert same.requires_grad is False and 0 < same.item() < 1
    x = noisy.clone().requires_grad_(True)
    (1 - ssim(x, a, padding="same")).backward()
    assert x.grad.abs().sum() > 0


def test_ssim_matches_the_closed_form_on_constant_images():
    # Constant images: variances are 0, so SSIM = (2 mx my + C1) / (mx^2 + my^2 + C1).
    a, b = torch.full((20, 20, 1), 0.3, dtype=torch.float64), torch.full((20, 20, 1), 0.6, dtype=torch.float64)
    expected = (2 * 0.3 * 0.6 + 0.01**2) / (0.3**2 + 0.6**2 + 0.01**2)
    assert ssim(a, b).item() == pytest.approx(expected, rel=1e-9)


def test_ms_ssim():
    a = image(2, 200, 240)
    assert ms_ssim(a, a) == pytest.approx(1.0, abs=1e-6)
    noisy = (a + 0.1 * torch.randn(a.shape, generator=torch.Generator().manual_seed(3))).clamp(0, 1)
    assert 0 < ms_ssim(noisy, a) < 1
    small = image(4, 40, 50)
    assert 0 < ms_ssim((small + 0.1).clamp(0, 1), small) < 1  # fewer scales, still defined


def test_depth_l1():
    gt = torch.tensor([[1.0, 0.0], [2.0, 3.0]])
    pred = torch.tensor([[1.1, 5.0], [2.0, 2.7]])
    assert depth_l1(pred, gt) == pytest.approx((0.1 + 0.0 + 0.3) / 3)
    assert math.isnan(depth_l1(pred, torch.zeros(2, 2)))


def test_confusion_matrix_miou():
    gt = np.array([[1, 1, 2, 2], [0, 0, 3, 3]])
    pred = np.array([[1, 2, 2, 2], [5, 5, 3, 1]])
    cm = ConfusionMatrix()
    cm.update(pred, gt)
    iou = cm.iou()
    # class 1: TP 1, FN 1, FP 1 -> 1/3; class 2: TP 2, FP 1 -> 2/3; class 3: TP 1, FN 1 -> 1/2
    assert iou == pytest.approx({1: 1 / 3, 2: 2 / 3, 3: 1 / 2})
    assert cm.miou() == pytest.approx((1 / 3 + 2 / 3 + 1 / 2) / 3)
    assert cm.pixel_accuracy() == pytest.approx(4 / 6)  # unlabelled ground truth is ignored
    cm.update(gt, gt)  # accumulates over frames
    assert cm.iou()[2] == pytest.approx(4 / 5)


def test_paper_protocol_ignores_classes_absent_from_the_frame():
    gt = np.array([1, 1, 2, 2, 0])
    pred = np.array([1, 1, 2, 1, 7])
    assert paper_frame_miou(pred, gt) == pytest.approx((2 / 3 + 1 / 2) / 2)


def test_lpips_reports_why_it_is_unavailable_and_is_zero_on_identical_images(monkeypatch):
    monkeypatch.delenv("SGS_SLAM_LPIPS_ALEXNET", raising=False)
    model, reason = load_lpips()
    assert model is None and "SGS_SLAM_LPIPS_ALEXNET" in reason
    torch.manual_seed(0)
    net = Lpips().eval()  # random weights: checks the plumbing, not calibrated values
    a = image(5, 64, 64)
    assert net(a, a).item() == pytest.approx(0.0, abs=1e-7)
    assert net((a + 0.2).clamp(0, 1), a).item() != 0.0
