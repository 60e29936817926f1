"""Adam's update written out in tensor operations: the form ``torch.compile`` fuses.

:class:`~sgs_slam_core.slam.adam.FusedAdam` runs PyTorch's fused Adam kernel once per tensor (two
launches each, with its step count). Compiled (``render.compile``), this function updates a tensor in
one generated kernel; run eagerly it is the reference the compiled form is tested against, and it
matches the fused kernel to rounding (tests).
"""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["BETAS", "adam_update"]

BETAS = (0.9, 0.999)


@torch.no_grad()
def adam_update(
    p: Tensor,  # updated in place
    grad: Tensor,  # like p
    exp_avg: Tensor,  # like p, updated in place
    exp_avg_sq: Tensor,  # like p, updated in place
    step: Tensor,  # [] float32: incremented before the update, as torch.optim.Adam does
    lr: float,
    eps: float,
) -> None:
    """One Adam step of ``p`` (betas :data:`BETAS`, no weight decay)."""
    beta1, beta2 = BETAS
    step.add_(1)
    exp_avg.lerp_(grad, 1 - beta1)
    exp_avg_sq.mul_(beta2).addcmul_(grad, grad, value=1 - beta2)
    count = step.double()  # the bias corrections in double precision, as torch.optim.Adam takes them
    step_size = (lr / (1 - beta1**count)).to(p.dtype)  # []
    denom = exp_avg_sq.sqrt() / (1 - beta2**count).sqrt().to(p.dtype) + eps
    p.sub_(step_size * (exp_avg / denom))
