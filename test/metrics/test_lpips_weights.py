"""LPIPS weights: the lpips package's linear layers are used; the table says what is still missing."""

import pytest
import torch

from sgs_slam_core.metrics import load_lpips
from sgs_slam_core.metrics.lpips import Lpips
from sgs_slam_core.metrics.lpips_weights import ALEXNET_FILE, find_lpips_weights
from sgs_slam_core.runner.report import format_table


@pytest.fixture
def no_weights(monkeypatch, tmp_path):
    """Nothing from the environment, an empty torch hub, no lpips package on the path."""
    monkeypatch.delenv("SGS_SLAM_LPIPS_ALEXNET", raising=False)
    monkeypatch.delenv("SGS_SLAM_LPIPS_LINEAR", raising=False)
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch_home"))
    real_find_spec = __import__("importlib").util.find_spec
    monkeypatch.setattr(
        "sgs_slam_core.metrics.lpips_weights.importlib.util.find_spec",
        lambda name: None if name == "lpips" else real_find_spec(name),
    )
    return tmp_path


def weights(seed: int) -> tuple[dict, dict]:
    """Random AlexNet (torchvision keys) and LPIPS linear state dicts of the right shapes."""
    torch.manual_seed(seed)
    model = Lpips()
    alexnet = {f"features.{k}": v.clone() for k, v in model.features.state_dict().items()}
    linear = {f"lin{i}.model.1.weight": torch.rand_like(lin.weight) for i, lin in enumerate(model.lins)}
    return alexnet, linear


def fake_lpips_package(root, linear) -> None:
    """An installed-looking ``lpips`` package that ships weights/v0.1/alex.pth (as the real wheel does)."""
    pkg = root / "site" / "lpips"
    (pkg / "weights" / "v0.1").mkdir(parents=True)
    (pkg / "__init__.py").write_text("raise ImportError('must not be imported: it needs torchvision')\n")
    torch.save(linear, pkg / "weights" / "v0.1" / "alex.pth")


def test_nothing_installed_names_both_parts(no_weights):
    found = find_lpips_weights()
    assert found.missing == ["AlexNet backbone", "LPIPS linear layers"]
    model, note = load_lpips()
    assert model is None and "pip install lpips" in note and "SGS_SLAM_LPIPS_ALEXNET" in note


def test_linear_layers_come_from_the_installed_lpips_package(no_weights, monkeypatch):
    _, linear = weights(0)
    fake_lpips_package(no_weights, linear)
    monkeypatch.undo()  # restore the real find_spec, keep the environment below
    monkeypatch.delenv("SGS_SLAM_LPIPS_ALEXNET", raising=False)
    monkeypatch.delenv("SGS_SLAM_LPIPS_LINEAR", raising=False)
    monkeypatch.setenv("TORCH_HOME", str(no_weights / "torch_home"))
    monkeypatch.syspath_prepend(str(no_weights / "site"))
    found = find_lpips_weights()
    assert found.linear == no_weights / "site" / "lpips" / "weights" / "v0.1" / "alex.pth"
    assert found.missing == ["AlexNet backbone"]
    model, note = load_lpips()
    assert model is None and note.startswith("AlexNet backbone missing; found the linear layers of the installed lpips")
    table = format_table({"lpips": None, "lpips_note": note})
    assert "LPIPS" in table and "AlexNet backbone missing" in table.splitlines()[-1]


def test_backbone_from_the_torch_hub_cache_completes_the_metric(no_weights, monkeypatch):
    alexnet, linear = weights(1)
    hub = no_weights / "torch_home" / "hub" / "checkpoints"
    hub.mkdir(parents=True)
    torch.save(alexnet, hub / ALEXNET_FILE)
    torch.save(linear, no_weights / "lin.pth")
    monkeypatch.setenv("SGS_SLAM_LPIPS_LINEAR", str(no_weights / "lin.pth"))
    found = find_lpips_weights()
    assert found.complete and found.alexnet == hub / ALEXNET_FILE and found.note() == ""
    model, note = load_lpips()
    assert note == "" and model is not None
    assert torch.equal(model.lins[2].weight, linear["lin2.model.1.weight"])
    img = torch.rand(64, 64, 3)
    assert float(model(img, img)) == 0.0 and float(model(img, torch.rand(64, 64, 3))) > 0


def test_unreadable_weights_are_reported_not_raised(no_weights, monkeypatch):
    (no_weights / "bad.pth").write_bytes(b"not a checkpoint")
    monkeypatch.setenv("SGS_SLAM_LPIPS_ALEXNET", str(no_weights / "bad.pth"))
    monkeypatch.setenv("SGS_SLAM_LPIPS_LINEAR", str(no_weights / "bad.pth"))
    model, note = load_lpips()
    assert model is None and "could not be loaded" in note
