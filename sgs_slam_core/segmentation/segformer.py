"""A pretrained indoor segmentation model as a label source: SegFormer trained on ADE20K, to NYU40 ids.

SegFormer (Xie et al., NeurIPS 2021) through Hugging Face ``transformers``: ADE20K's 150 classes
cover indoor scenes (wall, floor, ceiling, furniture, objects), the smallest variant (b0, 3.7 M
parameters) runs on a CPU, and larger ones (b1-b5) trade speed for accuracy on a GPU with the same
code. Weights come from the Hugging Face hub on first use (cached by the library) or from a folder
saved with ``save_pretrained``. ``transformers`` is an optional extra (``pip install
'sgs_slam_ros[segmentation]'``); it is imported only when a model is made.
"""

from __future__ import annotations

import numpy as np
import torch

from sgs_slam_core.errors import SgsSlamError
from sgs_slam_core.segmentation.ade20k import ADE20K_CLASSES, ade20k_to_nyu40_lut

__all__ = ["DEFAULT_MODEL", "SegmentationError", "Segmenter"]

DEFAULT_MODEL = "nvidia/segformer-b0-finetuned-ade-512-512"
_MEAN = (0.485, 0.456, 0.406)  # ImageNet statistics, as SegFormer's image processor normalises
_STD = (0.229, 0.224, 0.225)


class SegmentationError(SgsSlamError):
    """The segmentation model cannot be made (the extra is missing, the weights cannot be had)."""


def _transformers():  # the optional extra, imported when a model is made
    try:
        import transformers  # noqa: PLC0415 - optional dependency
    except ImportError as err:
        raise SegmentationError(
            "the segmentation model needs the optional extra: pip install 'sgs_slam_ros[segmentation]' "
            f"(transformers; {err})"
        ) from err
    return transformers


class Segmenter:
    """Colour image in, NYU40 class ids out (``lut`` maps the model's ADE20K classes)."""

    def __init__(self, model: torch.nn.Module, device: torch.device, name: str) -> None:
        if getattr(model.config, "num_labels", None) != len(ADE20K_CLASSES):
            raise SegmentationError(
                f"{name}: expected a model of ADE20K's {len(ADE20K_CLASSES)} classes, "
                f"got {getattr(model.config, 'num_labels', '?')}"
            )
        self.model = model.to(device).eval()
        self.device, self.name = device, name
        self.lut = torch.as_tensor(ade20k_to_nyu40_lut(), device=device)  # [150] ADE20K index -> NYU40 id
        self._mean = torch.tensor(_MEAN, device=device).view(3, 1, 1)
        self._std = torch.tensor(_STD, device=device).view(3, 1, 1)

    @classmethod
    def from_pretrained(cls, name_or_path: str = DEFAULT_MODEL, device: str | torch.device = "cpu") -> Segmenter:
        """The model from the hub (downloaded once, then cached) or a local folder; one-line error if unavailable."""
        tf = _transformers()
        try:
            model = tf.SegformerForSemanticSegmentation.from_pretrained(name_or_path)
        except (OSError, ValueError) as err:
            first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
            raise SegmentationError(
                f"cannot load the segmentation model {name_or_path!r} ({first}); without network, download it "
                f"once where there is one (it is cached under ~/.cache/huggingface) or give a folder saved with "
                "save_pretrained"
            ) from err
        return cls(model, torch.device(device), name_or_path)

    @classmethod
    def random(cls, device: str | torch.device = "cpu", seed: int = 0) -> Segmenter:
        """SegFormer-b0's architecture for ADE20K with random weights (tests, timing): no download."""
        tf = _transformers()
        torch.manual_seed(seed)
        model = tf.SegformerForSemanticSegmentation(tf.SegformerConfig(num_labels=len(ADE20K_CLASSES)))
        return cls(model, torch.device(device), "segformer-b0 (random weights)")

    @torch.inference_mode()
    def ade20k_classes(self, rgb: np.ndarray) -> torch.Tensor:  # rgb [H, W, 3] uint8 -> [H, W] int64
        """The model's ADE20K class index of every pixel (logits upsampled to the image size)."""
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
            raise SegmentationError(f"expected an HxWx3 uint8 colour image, got {rgb.shape} {rgb.dtype}")
        x = torch.from_numpy(np.ascontiguousarray(rgb)).to(self.device).permute(2, 0, 1).float() / 255.0
        x = ((x - self._mean) / self._std).unsqueeze(0)  # [1, 3, H, W]
        logits = self.model(pixel_values=x).logits  # [1, 150, H/4, W/4]
        up = torch.nn.functional.interpolate(logits, size=rgb.shape[:2], mode="bilinear", align_corners=False)
        return up[0].argmax(0)

    def __call__(self, rgb: np.ndarray) -> np.ndarray:  # rgb [H, W, 3] uint8 -> [H, W] uint16
        """NYU40 class ids of every pixel (0 = unlabelled: outdoor ADE20K classes)."""
        return self.lut[self.ade20k_classes(rgb)].cpu().numpy().astype(np.uint16)
