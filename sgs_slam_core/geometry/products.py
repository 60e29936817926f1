"""Matrix products that ``torch.compile`` fuses into the kernels around them."""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["fusable_matmul"]


def fusable_matmul(a: Tensor, b: Tensor) -> Tensor:  # [..., M, K] @ [..., K, N] -> [..., M, N]
    """``a @ b``; while ``torch.compile`` traces, a broadcast product summed over K.

    Inductor turns a matrix product into a call of its own (a kernel launch on a GPU), but fuses a
    product and a sum into the element-wise work before and after it: for the 3x3 and 4x4 products
    of a pose update, and an [N, 7] row block's 7x7 normal matrix, one kernel instead of several.
    Eagerly the matrix product is fewer operations and less memory.
    """
    if torch.compiler.is_compiling():
        return (a[..., :, :, None] * b[..., None, :, :]).sum(-2)
    return a @ b
