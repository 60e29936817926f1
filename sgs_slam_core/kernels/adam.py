"""Adam's update written out in tensor operations: the form ``torch.compile`` fuses.

:class:`~sgs_slam_core.slam.adam.FusedAdam` runs PyTorch's fused Adam kernel once per tensor (two
launches each, with its step count). Compiled (``render.compile``), this function updates a tensor in
one generated kernel; run eagerly it is the reference the compiled form is tested against, and it
matches the fused kernel to rounding (tests).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

__all__ = ["BETAS", "adam_update"]

BETAS = (0.9, 0.999)


@torch.no_grad()
def adam_update(
    params: Sequence[Tensor],  # each updated in place
    grads: Sequence[Tensor],  # like params
    exp_avgs: Sequence[Tensor],  # like params, updated in place
    exp_avg_sqs: Sequence[Tensor],  # like params, updated in place
    steps: Sequence[Tensor],  # [] float32 each: incremented before the update, as torch.optim.Adam does
    lrs: Sequence[float],
    eps: float,
) -> None:
    """One Adam step (betas :data:`BETAS`, no weight decay) of each ``params[i]`` at ``lrs[i]``."""
    beta1, beta2 = BETAS
    for p, g, m, v, step, lr in zip(params, grads, exp_avgs, exp_avg_sqs, steps, lrs, strict=True):
        step.add_(1)
        m.lerp_(g, 1 - beta1)
        v.mul_(beta2).addcmul_(g, g, value=1 - beta2)
        count = step.double()  # the bias corrections in double precision, as torch.optim.Adam takes them
        step_size = (lr / (1 - beta1**count)).to(p.dtype)  # []
        denom = v.sqrt() / (1 - beta2**count).sqrt().to(p.dtype) + eps
        p.sub_(step_size * (m / denom))
