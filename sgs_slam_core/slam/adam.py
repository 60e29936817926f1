"""Adam for a few named tensors, each with its own learning rate, in one fused kernel call per tensor.

``torch.optim.Adam(fused=True)`` runs the same kernel (``torch._fused_adam_``) but spends more time
around it than in it on the SLAM's small steps. The update is the library's fused kernel, with the
same step counting (incremented before the update, as ``torch.optim.Adam`` does); the CPU and CUDA
both have it, so this is the one optimiser step of every kernel backend, unless an ``update`` is
given (``render.compile``: :func:`~sgs_slam_core.kernels.adam.adam_update` compiled).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from sgs_slam_core.kernels.adam import BETAS
from sgs_slam_core.kernels.base import AdamUpdate

__all__ = ["AdamMoments", "FusedAdam"]


@dataclass
class AdamMoments:
    """One tensor's optimiser state."""

    exp_avg: Tensor  # like the parameter
    exp_avg_sq: Tensor  # like the parameter
    step: Tensor  # [] float32 on the parameter's device


class FusedAdam:
    """Adam (betas 0.9, 0.999, no weight decay) over ``params[name]`` with ``lrs[name]``.

    ``params`` is held by reference: :meth:`replace` swaps a tensor (e.g. after pruning) together with
    its sliced moments. ``update`` (:func:`~sgs_slam_core.kernels.adam.adam_update`'s signature) runs
    each tensor's step in place of the fused kernel.
    """

    def __init__(
        self, params: dict[str, Tensor], lrs: dict[str, float], eps: float = 1e-8, update: AdamUpdate | None = None
    ) -> None:
        self.params, self.lrs, self.eps, self.update = params, lrs, eps, update
        self.state: dict[str, AdamMoments] = {}

    def step(self) -> None:
        """One update of every tensor that has a gradient, then the gradients are cleared."""
        with torch.no_grad():
            for name, p in self.params.items():
                if p.grad is None:
                    continue
                s = self.state.get(name)
                if s is None:
                    s = AdamMoments(torch.zeros_like(p), torch.zeros_like(p), torch.zeros((), device=p.device))
                    self.state[name] = s
                # a call per tensor: which tensors have a gradient changes from step to step (a frame
                # without labels leaves the semantics out); one compiled graph per tensor serves all
                if self.update is not None:
                    self.update(p, p.grad, s.exp_avg, s.exp_avg_sq, s.step, self.lrs[name], self.eps)
                else:
                    self._fused(name, p, s)
                p.grad = None

    def _fused(self, name: str, p: Tensor, s: AdamMoments) -> None:
        s.step += 1
        torch._fused_adam_(  # the kernel behind torch.optim.Adam(fused=True)
            [p],
            [p.grad],
            [s.exp_avg],
            [s.exp_avg_sq],
            [],  # max_exp_avg_sqs (no amsgrad)
            [s.step],
            lr=self.lrs[name],
            beta1=BETAS[0],
            beta2=BETAS[1],
            weight_decay=0.0,
            eps=self.eps,
            amsgrad=False,
            maximize=False,
        )

    def replace(self, name: str, new: Tensor, rows: Tensor | None = None) -> None:
        """Swap ``params[name]`` for ``new``; its moments keep ``rows`` (a [N] bool or [M] int64 index) when given."""
        self.params[name] = new
        s = self.state.get(name)
        if s is not None and rows is not None:
            index = rows.nonzero().squeeze(1) if rows.dtype == torch.bool else rows
            self.state[name] = AdamMoments(
                s.exp_avg.index_select(0, index), s.exp_avg_sq.index_select(0, index), s.step
            )
        elif s is not None:
            del self.state[name]
