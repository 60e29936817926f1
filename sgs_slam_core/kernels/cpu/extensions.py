"""The compiled CPU kernels' C++ sources (beside this file), each built into its own module on first use."""

from __future__ import annotations

from pathlib import Path

from sgs_slam_core.native import NativeExtension

__all__ = ["EXTENSIONS", "GAUSS_NEWTON", "PHOTOMETRIC", "RENDER"]

_HERE = Path(__file__).parent

RENDER = NativeExtension("render", _HERE / "raster.cpp", "the CPU renderer")
PHOTOMETRIC = NativeExtension("photometric", _HERE / "photometric.cpp", "the CPU losses")
GAUSS_NEWTON = NativeExtension("gauss_newton", _HERE / "gauss_newton.cpp", "the Gauss-Newton tracker's CPU kernel")
EXTENSIONS = (RENDER, PHOTOMETRIC, GAUSS_NEWTON)
