"""The Gaussian map: one row per Gaussian, in the world (map) frame.

Operations are functional: they return a new :class:`GaussianMap` and never modify the tensors of
the one they are called on (unchanged tensors are shared, not copied).
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import torch
from torch import Tensor

from sgs_slam_core.errors import ShapeError
from sgs_slam_core.geometry.se3 import quat_multiply, rotmat_to_quat

__all__ = ["GaussianMap"]

_OPTIMISED = ("means", "log_scales", "logit_opacities", "colors", "semantics")


@dataclass(frozen=True)
class GaussianMap:
    """Gaussian parameters (pre-activation where an activation applies).

    Isotropic maps have ``log_scales [N, 1]`` and ``quats is None``; anisotropic maps have
    ``log_scales [N, 3]`` and ``quats [N, 4]`` (wxyz, world frame).
    """

    means: Tensor  # [N, 3] world frame (m)
    log_scales: Tensor  # [N, 1] or [N, 3], log of the standard deviation (m)
    logit_opacities: Tensor  # [N]
    colors: Tensor  # [N, 3] linear RGB in [0, 1] (not clamped while optimising)
    semantics: Tensor  # [N, S] semantic features (S = 3 in colour mode, K classes in one-hot mode)
    labels: Tensor  # [N] int64 class id (0 = unlabelled), not optimised
    birth_frame: Tensor  # [N] int64 frame index at which the Gaussian was added
    quats: Tensor | None = None  # [N, 4] wxyz, anisotropic maps only
    label_weight: Tensor | None = None  # [N] float32 views' net agreement with ``labels`` (votes); None: zeros

    def __post_init__(self) -> None:
        if self.label_weight is None:  # maps saved without votes, and code that never casts any
            object.__setattr__(self, "label_weight", torch.zeros(self.means.shape[0], device=self.means.device))
        self.validate()

    # ------------------------------------------------------------------ construction
    @staticmethod
    def empty(
        num_semantic: int,
        anisotropic: bool = False,
        device: torch.device | str = "cpu",
        dtype: torch.dtype = torch.float32,
    ) -> GaussianMap:
        """A map with no Gaussians and ``num_semantic`` semantic channels."""
        z = {"device": device, "dtype": dtype}
        return GaussianMap(
            means=torch.zeros(0, 3, **z),
            log_scales=torch.zeros(0, 3 if anisotropic else 1, **z),
            logit_opacities=torch.zeros(0, **z),
            colors=torch.zeros(0, 3, **z),
            semantics=torch.zeros(0, num_semantic, **z),
            labels=torch.zeros(0, dtype=torch.long, device=device),
            birth_frame=torch.zeros(0, dtype=torch.long, device=device),
            quats=torch.zeros(0, 4, **z) if anisotropic else None,
        )

    def validate(self) -> None:
        """Raise :class:`ShapeError` unless every field has a consistent shape, dtype and device."""
        n = self.means.shape[0] if self.means.ndim == 2 else -1
        if self.means.ndim != 2 or self.means.shape[1] != 3:
            raise ShapeError(f"means must be [N, 3], got {tuple(self.means.shape)}")
        expected = {
            "logit_opacities": (n,),
            "colors": (n, 3),
            "labels": (n,),
            "birth_frame": (n,),
            "label_weight": (n,),
        }
        for name, shape in expected.items():
            got = tuple(getattr(self, name).shape)
            if got != shape:
                raise ShapeError(f"{name} must be {list(shape)} for N={n}, got {list(got)}")
        if self.semantics.ndim != 2 or self.semantics.shape[0] != n:
            raise ShapeError(f"semantics must be [N, S] for N={n}, got {list(self.semantics.shape)}")
        width = 1 if self.quats is None else 3
        if tuple(self.log_scales.shape) != (n, width):
            raise ShapeError(f"log_scales must be [N, {width}] for this map, got {list(self.log_scales.shape)}")
        if self.quats is not None and tuple(self.quats.shape) != (n, 4):
            raise ShapeError(f"quats must be [N, 4], got {list(self.quats.shape)}")
        for name in ("labels", "birth_frame"):
            if getattr(self, name).dtype != torch.long:
                raise ShapeError(f"{name} must be int64, got {getattr(self, name).dtype}")
        devices = {t.device for t in self._tensors().values()}
        if len(devices) > 1:
            raise ShapeError(f"all tensors must be on one device, got {sorted(map(str, devices))}")

    # ------------------------------------------------------------------ properties
    def __len__(self) -> int:
        return self.means.shape[0]

    @property
    def num_semantic(self) -> int:
        """Semantic channels per Gaussian (S)."""
        return self.semantics.shape[1]

    @property
    def isotropic(self) -> bool:
        """True when every Gaussian is a sphere (one scale, no rotation)."""
        return self.quats is None

    @property
    def device(self) -> torch.device:
        """Device holding the tensors."""
        return self.means.device

    @property
    def opacities(self) -> Tensor:  # [N] in (0, 1)
        """Activated opacities."""
        return torch.sigmoid(self.logit_opacities)

    @property
    def scales(self) -> Tensor:  # [N, 1] or [N, 3] (m)
        """Activated standard deviations."""
        return torch.exp(self.log_scales)

    def _tensors(self) -> dict[str, Tensor]:
        return {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) is not None}

    # ------------------------------------------------------------------ functional edits
    def cat(self, other: GaussianMap) -> GaussianMap:
        """This map followed by ``other`` (same S, same isotropy)."""
        if other.num_semantic != self.num_semantic or other.isotropic != self.isotropic:
            raise ShapeError(
                f"cannot join maps: S={self.num_semantic}/{other.num_semantic}, "
                f"isotropic={self.isotropic}/{other.isotropic}"
            )
        mine, theirs = self._tensors(), other._tensors()
        return GaussianMap(**{k: torch.cat([v, theirs[k].to(v.device)]) for k, v in mine.items()})

    def select(self, mask: Tensor) -> GaussianMap:  # mask: [N] bool or [M] int64 indices
        """The Gaussians picked by a boolean mask or an index tensor."""
        if mask.dtype == torch.bool and tuple(mask.shape) != (len(self),):
            raise ShapeError(f"mask must be [N]={len(self)}, got {list(mask.shape)}")
        mask = mask.to(self.device)
        index = mask.nonzero().squeeze(1) if mask.dtype == torch.bool else mask  # gathers beat mask indexing
        return GaussianMap(**{k: v.index_select(0, index) for k, v in self._tensors().items()})

    def prune(self, remove: Tensor) -> GaussianMap:  # remove: [N] bool
        """Drop the Gaussians where ``remove`` is True."""
        if remove.dtype != torch.bool:
            raise ShapeError(f"prune takes a boolean mask, got {remove.dtype}")
        return self.select(~remove)

    def transformed(self, pose: Tensor, mask: Tensor | None = None) -> GaussianMap:
        """Apply a rigid transform ``pose [4, 4]`` (world -> world) to all or the masked Gaussians."""
        if tuple(pose.shape) != (4, 4):
            raise ShapeError(f"pose must be [4, 4], got {list(pose.shape)}")
        pose = pose.to(self.means)
        sel = torch.ones(len(self), dtype=torch.bool, device=self.device) if mask is None else mask.to(self.device)
        if tuple(sel.shape) != (len(self),) or sel.dtype != torch.bool:
            raise ShapeError(f"mask must be a [N]={len(self)} bool tensor")
        moved = self.means @ pose[:3, :3].T + pose[:3, 3]
        means = torch.where(sel[:, None], moved, self.means)
        quats = self.quats
        if quats is not None:
            q_pose = rotmat_to_quat(pose[:3, :3]).expand_as(quats)
            quats = torch.where(sel[:, None], quat_multiply(q_pose, quats), quats)
        return replace(self, means=means, quats=quats)

    def to(self, device: torch.device | str) -> GaussianMap:
        """Copy to another device."""
        return GaussianMap(**{k: v.to(device) for k, v in self._tensors().items()})

    def detach(self) -> GaussianMap:
        """Same values, cut from autograd."""
        return GaussianMap(**{k: v.detach() for k, v in self._tensors().items()})

    def clone(self) -> GaussianMap:
        """Deep copy (detached)."""
        return GaussianMap(**{k: v.detach().clone() for k, v in self._tensors().items()})

    def with_tensors(self, **tensors: Tensor) -> GaussianMap:
        """A copy with some fields replaced (validated)."""
        return replace(self, **tensors)

    # ------------------------------------------------------------------ persistence
    def state_dict(self) -> dict[str, Tensor]:
        """Detached CPU tensors keyed by field name (``quats`` only when anisotropic)."""
        return {k: v.detach().cpu() for k, v in self._tensors().items()}

    @staticmethod
    def from_state_dict(state: dict[str, Tensor], device: torch.device | str = "cpu") -> GaussianMap:
        """Inverse of :meth:`state_dict`; missing or unknown fields raise :class:`ShapeError`."""
        optional = {"quats", "label_weight"}
        required = {f.name for f in fields(GaussianMap)} - optional
        missing = required - state.keys()
        unknown = state.keys() - required - optional
        if missing or unknown:
            raise ShapeError(f"bad Gaussian state: missing {sorted(missing)}, unknown {sorted(unknown)}")
        return GaussianMap(**{k: v.to(device) for k, v in state.items()})

    @staticmethod
    def optimised_fields(anisotropic: bool) -> tuple[str, ...]:
        """Names of the fields an optimiser updates."""
        return (*_OPTIMISED, "quats") if anisotropic else _OPTIMISED
