"""A pretrained indoor segmentation model as a label source: SegFormer trained on ADE20K, to NYU40 ids.

SegFormer (Xie et al., NeurIPS 2021) through Hugging Face ``transformers``: ADE20K's 150 classes
cover indoor scenes (wall, floor, ceiling, furniture, objects), the smallest variant (b0, 3.7 M
parameters) runs on a CPU, and larger ones (b1-b5) trade speed for accuracy on a GPU with the same
code. Weights come from the Hugging Face hub on first use (cached by the library) or from a folder
saved with ``save_pretrained``. ``transformers`` is an optional extra (``pip install
'sgs_slam_ros[segmentation]'``); it is imported only when a model is made.
"""

from __future__ import annotations

import cv2
import numpy as np
import torch

from sgs_slam_core.errors import SgsSlamError
from sgs_slam_core.segmentation.ade20k import ADE20K_CLASSES, ade20k_to_nyu40_lut

__all__ = ["DEFAULT_MODEL", "MIN_SIDE_PX", "SegmentationError", "Segmenter"]

DEFAULT_MODEL = "nvidia/segformer-b0-finetuned-ade-512-512"
MIN_SIDE_PX = 32  # SegFormer's smallest input: its four stages stride the image down 32 times
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
    def ade20k_classes(self, rgb: np.ndarray, downscale: float = 1.0) -> torch.Tensor:  # [H, W, 3] uint8 -> [H, W]
        """The model's ADE20K class index (int64) of every pixel; the model sees the image ``downscale`` x smaller.

        The logits are upsampled to the image's size either way, so a smaller input costs detail at
        class boundaries, not pixels: the model's time falls with the pixels it sees. The model's
        input keeps at least ``MIN_SIDE_PX`` a side (a larger ``downscale`` is reduced to that).
        """
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
            raise SegmentationError(f"expected an HxWx3 uint8 colour image, got {rgb.shape} {rgb.dtype}")
        if not 1.0 <= downscale <= 16.0:
            raise SegmentationError(f"downscale must be in [1, 16], got {downscale}")
        h, w = rgb.shape[:2]
        if min(h, w) < MIN_SIDE_PX:
            raise SegmentationError(f"a {w}x{h} image is too small for SegFormer (at least {MIN_SIDE_PX} px a side)")
        seen = rgb
        downscale = min(downscale, min(h, w) / MIN_SIDE_PX)  # the model's smallest input, not an error
        if downscale > 1.0:
            size = (max(MIN_SIDE_PX, round(w / downscale)), max(MIN_SIDE_PX, round(h / downscale)))
            seen = cv2.resize(rgb, size, interpolation=cv2.INTER_AREA)
        x = torch.from_numpy(np.ascontiguousarray(seen)).to(self.device).permute(2, 0, 1).float() / 255.0
        x = ((x - self._mean) / self._std).unsqueeze(0)  # [1, 3, h, w]
        logits = self.model(pixel_values=x).logits  # [1, 150, h/4, w/4]
        up = torch.nn.functional.interpolate(logits, size=rgb.shape[:2], mode="bilinear", align_corners=False)
        return up[0].argmax(0)

    def __call__(self, rgb: np.ndarray, downscale: float = 1.0) -> np.ndarray:  # [H, W, 3] uint8 -> [H, W] uint16
        """NYU40 class ids of every pixel (0 = unlabelled: outdoor ADE20K classes); see :meth:`ade20k_classes`."""
        return self.lut[self.ade20k_classes(rgb, downscale)].cpu().numpy().astype(np.uint16)
