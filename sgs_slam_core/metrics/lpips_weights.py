"""Where the two LPIPS weight files come from, and which one is missing.

LPIPS (AlexNet) needs the AlexNet ImageNet backbone (torchvision's ``alexnet-owt-7be5be79.pth``)
and the LPIPS linear heads (``weights/v0.1/alex.pth``). Sources, first found wins:

* linear heads: ``$SGS_SLAM_LPIPS_LINEAR``, else the installed ``lpips`` package, which ships them
  (``pip install lpips``; the package is located, never imported, so torchvision is not needed);
* backbone: ``$SGS_SLAM_LPIPS_ALEXNET``, else torch hub's cache (``$TORCH_HOME/hub/checkpoints``),
  where torchvision keeps it after ``alexnet(weights="DEFAULT")`` has downloaded it once.
"""

from __future__ import annotations

import importlib.util
import os
from dataclasses import dataclass
from pathlib import Path

import torch

__all__ = ["ALEXNET_FILE", "LpipsWeights", "find_lpips_weights"]

ALEXNET_FILE = "alexnet-owt-7be5be79.pth"
_LINEAR_IN_PACKAGE = ("weights", "v0.1", "alex.pth")


@dataclass(frozen=True)
class LpipsWeights:
    """The weight files found (None where missing) and where each came from."""

    linear: Path | None
    alexnet: Path | None
    linear_source: str = ""
    alexnet_source: str = ""

    @property
    def complete(self) -> bool:
        """Both files are there."""
        return self.linear is not None and self.alexnet is not None

    @property
    def missing(self) -> list[str]:
        """Human names of the missing parts."""
        return [
            name for name, p in (("AlexNet backbone", self.alexnet), ("LPIPS linear layers", self.linear)) if p is None
        ]

    def note(self) -> str:
        """Why LPIPS is not reported, naming what was found and how to supply the rest ('' when complete)."""
        if self.complete:
            return ""
        fixes = []
        if self.alexnet is None:
            fixes.append(f"set SGS_SLAM_LPIPS_ALEXNET to torchvision's {ALEXNET_FILE}")
        if self.linear is None:
            fixes.append("pip install lpips (ships the linear layers) or set SGS_SLAM_LPIPS_LINEAR to its alex.pth")
        found = f"; found the {self.linear_source or self.alexnet_source}" if self.linear or self.alexnet else ""
        return f"{' and '.join(self.missing)} missing{found}: {'; '.join(fixes)}"


def _from_env(name: str) -> Path | None:
    value = os.environ.get(name)
    return Path(value) if value and Path(value).is_file() else None


def _lpips_package_file() -> Path | None:
    spec = importlib.util.find_spec("lpips")
    if spec is None or not spec.submodule_search_locations:
        return None
    for root in spec.submodule_search_locations:
        candidate = Path(root).joinpath(*_LINEAR_IN_PACKAGE)
        if candidate.is_file():
            return candidate
    return None


def _hub_alexnet() -> Path | None:
    candidate = Path(torch.hub.get_dir()) / "checkpoints" / ALEXNET_FILE
    return candidate if candidate.is_file() else None


def find_lpips_weights() -> LpipsWeights:
    """Look for both files in the documented places."""
    linear, linear_source = _from_env("SGS_SLAM_LPIPS_LINEAR"), "linear layers from SGS_SLAM_LPIPS_LINEAR"
    if linear is None:
        linear, linear_source = _lpips_package_file(), "linear layers of the installed lpips package"
    alexnet, alexnet_source = _from_env("SGS_SLAM_LPIPS_ALEXNET"), "AlexNet backbone from SGS_SLAM_LPIPS_ALEXNET"
    if alexnet is None:
        alexnet, alexnet_source = _hub_alexnet(), "AlexNet backbone in the torch hub cache"
    return LpipsWeights(linear, alexnet, linear_source if linear else "", alexnet_source if alexnet else "")
