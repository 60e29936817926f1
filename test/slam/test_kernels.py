"""The kernels are chosen once, by the factory: the reference is pure PyTorch, the choice is cached."""

from __future__ import annotations

import pytest
import torch

from sgs_slam_core.config import load_config
from sgs_slam_core.datasets import open_dataset
from sgs_slam_core.errors import BackendUnavailableError
from sgs_slam_core.geometry.icp import IcpKernels
from sgs_slam_core.kernels import build_kernels, factory
from sgs_slam_core.kernels.cpu.extensions import EXTENSIONS
from sgs_slam_core.native import NativeExtension
from sgs_slam_core.render import RenderSettings
from sgs_slam_core.slam.system import Slam

from ..conftest import FAST_SLAM


@pytest.mark.parametrize("method", ["adam", "gauss_newton"])
def test_the_reference_backend_never_touches_a_compiled_kernel(tiny_scene, monkeypatch, method):
    def refuse(self, *args, **kwargs):
        raise AssertionError(f"{self.what} was asked for on render.backend=torch")

    for name in ("module", "is_available", "is_cached", "variant"):
        monkeypatch.setattr(NativeExtension, name, refuse)
    monkeypatch.setattr(factory, "_CACHE", {})
    tiny = open_dataset(tiny_scene)
    overrides = [*FAST_SLAM, "render.backend=torch", f"tracking.method={method}", "tracking.adam.iterations=4"]
    slam = Slam(load_config("synthetic", overrides=overrides), tiny.label_table)
    slam.prepare(lambda line: pytest.fail(f"announced {line!r}"))
    for i in range(3):
        slam.process(tiny[i])
    assert slam.kernels.name == "torch" and slam.kernels.icp == IcpKernels()
    assert slam.render_view(tiny[2].gt_c2w).backend == "torch"


def test_kernels_are_built_once_per_settings_and_device():
    settings = RenderSettings(backend="torch")
    assert build_kernels(settings, "cpu") is build_kernels(RenderSettings(backend="torch"), torch.device("cpu"))
    assert build_kernels(settings, "cpu") is not build_kernels(RenderSettings(backend="torch", tile_size=16), "cpu")


def test_named_backends_that_cannot_run_raise():
    with pytest.raises(BackendUnavailableError, match="CPU tensors"):
        build_kernels(RenderSettings(backend="cpu"), "meta")
    with pytest.raises(BackendUnavailableError, match="CUDA"):
        build_kernels(RenderSettings(backend="gsplat"), "cpu")


@pytest.mark.skipif(not all(ext.is_available() for ext in EXTENSIONS), reason="no compiler")
def test_auto_on_the_cpu_is_the_compiled_kernels_everywhere():
    kernels = build_kernels(RenderSettings(), "cpu")
    assert (
        kernels.name == "cpu"
        and kernels.icp.terms is not None
        and kernels.icp.level is not None
        and kernels.direct_mapping(True)
    )
