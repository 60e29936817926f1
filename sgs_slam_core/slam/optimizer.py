"""Adam over the Gaussian map's fields, with pruning and growth that keep the moments aligned."""

from __future__ import annotations

import torch
from torch import Tensor

from sgs_slam_core.config.sections import MappingSettings
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.kernels.base import AdamUpdate
from sgs_slam_core.slam.adam import FusedAdam

__all__ = ["GaussianOptimizer"]


class GaussianOptimizer:
    """Leaf tensors for every optimised field and one Adam (eps 1e-15) with per-field learning rates.

    ``prune(keep)`` slices parameters *and* Adam moments, so the step after a prune updates the
    surviving Gaussians normally (the reference rebuilt the tensors and lost that step).
    Gaussians of ``frozen_labels`` get no gradient (so a fresh Adam leaves them bit-identical) and
    are never pruned.
    """

    def __init__(
        self,
        gaussians: GaussianMap,
        settings: MappingSettings,
        frozen_labels: frozenset[int] = frozenset(),
        update: AdamUpdate | None = None,
    ) -> None:
        """``update``: Adam's step of a field (``kernels.mapping.update``), else the fused kernel."""
        self._labels, self._birth, self._weight = gaussians.labels, gaussians.birth_frame, gaussians.label_weight
        self._frozen_ids = torch.tensor(sorted(frozen_labels), dtype=torch.int64, device=gaussians.device)
        lrs = {
            "means": settings.lr_means,
            "log_scales": settings.lr_scales,
            "logit_opacities": settings.lr_opacities,
            "colors": settings.lr_colors,
            "semantics": settings.lr_semantics,
            "quats": settings.lr_quats,
        }
        self.names = GaussianMap.optimised_fields(not gaussians.isotropic)
        self.params = {n: getattr(gaussians, n).detach().clone().requires_grad_(True) for n in self.names}
        # fused: one kernel call per field, less overhead than torch.optim's step
        self.adam = FusedAdam(self.params, {n: lrs[n] for n in self.names}, eps=1e-15, update=update)

    def gaussians(self) -> GaussianMap:
        """The map built on the live parameters (differentiable)."""
        return GaussianMap(labels=self._labels, birth_frame=self._birth, label_weight=self._weight, **self.params)

    def result(self) -> GaussianMap:
        """The optimised map, detached."""
        return self.gaussians().detach()

    def frozen(self) -> Tensor | None:  # [N] bool
        """Rows that must not change, None when nothing is frozen."""
        if self._frozen_ids.numel() == 0:
            return None
        return torch.isin(self._labels, self._frozen_ids)

    def step(self) -> None:
        """One Adam step (frozen rows get zero gradient), then clear gradients."""
        frozen = self.frozen()
        if frozen is not None:
            for p in self.params.values():
                if p.grad is not None:
                    p.grad[frozen] = 0
        self.adam.step()

    @torch.no_grad()
    def cap_scales(self, w2c: Tensor, k: Intrinsics, max_px: float) -> None:  # w2c [4, 4]
        """Shrink Gaussians seen by camera ``w2c`` to at most ``max_px`` px of standard deviation at their depth.

        Only centres projecting into the image count: one beside the camera, near its image plane,
        would get a needlessly small bound. Frozen Gaussians stay. A projection of the parameters, as
        after any constrained step: the Adam moments are kept.
        """
        log_scales, means = self.params["log_scales"], self.params["means"]
        rot, trans = w2c[:3, :3].to(means.dtype), w2c[:3, 3].to(means.dtype)
        x, y, z = (means @ rot.T + trans).unbind(-1)  # [N] camera frame (m)
        z_safe = z.clamp_min(1e-6)
        u, v = k.fx * x / z_safe + k.cx, k.fy * y / z_safe + k.cy
        seen = (z > 0) & (u >= -0.5) & (u <= k.width - 0.5) & (v >= -0.5) & (v <= k.height - 0.5)
        cap = torch.log(z_safe * (2 * max_px / (k.fx + k.fy)))[:, None]  # [N, 1]
        shrink = seen[:, None] & (log_scales > cap)
        frozen = self.frozen()
        if frozen is not None:
            shrink &= ~frozen[:, None]
        log_scales.copy_(torch.where(shrink, cap, log_scales))

    def prune(self, keep: Tensor) -> int:  # keep: [N] bool
        """Drop Gaussians where ``keep`` is False (frozen ones stay); returns how many were removed."""
        frozen = self.frozen()
        if frozen is not None:
            keep = keep | frozen
        rows = keep.nonzero().squeeze(1)  # gathers by index: a third of the time of indexing each tensor by the mask
        removed = keep.numel() - rows.numel()
        if removed == 0:
            return 0
        for name in self.names:
            self.adam.replace(name, self.params[name].detach().index_select(0, rows).requires_grad_(True), rows)
        self._labels, self._birth = self._labels.index_select(0, rows), self._birth.index_select(0, rows)
        self._weight = self._weight.index_select(0, rows)
        return removed
