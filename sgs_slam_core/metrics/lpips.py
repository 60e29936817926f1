"""LPIPS (AlexNet variant, Zhang et al. 2018), computed only when pretrained weights are on disk.

The weights cannot be downloaded here; :mod:`sgs_slam_core.metrics.lpips_weights` finds them (the
``lpips`` package ships the linear heads; the AlexNet backbone comes from ``SGS_SLAM_LPIPS_ALEXNET``
or torch hub's cache). Without both, :func:`load_lpips` returns ``(None, reason)`` and reports carry
``null`` with that reason, naming the part that is missing.
"""

from __future__ import annotations

import pickle
import zipfile

import torch
from torch import Tensor, nn

from sgs_slam_core.metrics.lpips_weights import find_lpips_weights

__all__ = ["Lpips", "load_lpips"]

_SHIFT = (-0.030, -0.088, -0.188)
_SCALE = (0.458, 0.448, 0.450)
_CHANNELS = (64, 192, 384, 256, 256)


class Lpips(nn.Module):
    """AlexNet features (torchvision layout) + LPIPS linear heads."""

    def __init__(self) -> None:
        super().__init__()
        self.features = nn.Sequential(
            nn.Conv2d(3, 64, 11, 4, 2),
            nn.ReLU(),
            nn.MaxPool2d(3, 2),
            nn.Conv2d(64, 192, 5, padding=2),
            nn.ReLU(),
            nn.MaxPool2d(3, 2),
            nn.Conv2d(192, 384, 3, padding=1),
            nn.ReLU(),
            nn.Conv2d(384, 256, 3, padding=1),
            nn.ReLU(),
            nn.Conv2d(256, 256, 3, padding=1),
            nn.ReLU(),
        )
        self.taps = (1, 4, 7, 9, 11)  # outputs of relu1..relu5
        self.lins = nn.ModuleList(nn.Conv2d(c, 1, 1, bias=False) for c in _CHANNELS)
        self.register_buffer("shift", torch.tensor(_SHIFT).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor(_SCALE).view(1, 3, 1, 1))

    def _feats(self, x: Tensor) -> list[Tensor]:
        x = (x - self.shift) / self.scale
        out = []
        for i, layer in enumerate(self.features):
            x = layer(x)
            if i in self.taps:
                out.append(x / (x.pow(2).sum(1, keepdim=True).sqrt() + 1e-10))
        return out

    @torch.no_grad()
    def forward(self, pred: Tensor, gt: Tensor) -> Tensor:
        """LPIPS distance of ``[H, W, 3]`` images in [0, 1] (inputs are clamped)."""
        a = pred.clamp(0, 1).permute(2, 0, 1)[None] * 2 - 1
        b = gt.clamp(0, 1).permute(2, 0, 1)[None] * 2 - 1
        total = torch.zeros((), device=a.device)
        for lin, fa, fb in zip(self.lins, self._feats(a), self._feats(b), strict=True):
            total = total + lin((fa - fb) ** 2).mean()
        return total

    def load(self, alexnet: dict[str, Tensor], linear: dict[str, Tensor]) -> None:
        """Load torchvision AlexNet (``features.*``) and LPIPS (``linK.model.1.weight``) state dicts."""
        feats = {k[len("features.") :]: v for k, v in alexnet.items() if k.startswith("features.")}
        self.features.load_state_dict(feats)
        for i, lin in enumerate(self.lins):
            lin.weight.data.copy_(linear[f"lin{i}.model.1.weight"])


# what torch.load and load_state_dict raise for a file that is not the expected state dict
_LOAD_ERRORS = (
    OSError,
    RuntimeError,
    KeyError,
    ValueError,
    AttributeError,
    EOFError,
    pickle.UnpicklingError,
    zipfile.BadZipFile,
)


def load_lpips(device: torch.device | str = "cpu") -> tuple[Lpips | None, str]:
    """The metric with pretrained weights, or ``(None, why not)``."""
    weights = find_lpips_weights()
    if weights.alexnet is None or weights.linear is None:
        return None, weights.note()
    try:
        model = Lpips()
        model.load(torch.load(weights.alexnet, map_location="cpu"), torch.load(weights.linear, map_location="cpu"))
    except _LOAD_ERRORS as err:
        return None, (
            f"LPIPS weights could not be loaded from {weights.alexnet} and {weights.linear}: "
            f"{type(err).__name__}: {err}"
        )
    return model.eval().to(device), ""
