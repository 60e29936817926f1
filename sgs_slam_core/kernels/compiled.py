"""The ICP's steps, terms and reference level, the mapping loss and Adam's update through ``torch.compile``.

Inductor fuses a Gauss-Newton step's hundred-odd tensor operations into a few kernels (Triton on
CUDA, C++ on the CPU), so a step costs a few launches instead of one per operation. The compiled
code is the PyTorch code itself (:func:`~sgs_slam_core.geometry.icp.torch_step`, ``torch_joint_step``,
``torch_terms``, ``torch_level``; :func:`~sgs_slam_core.kernels.losses.mapping_loss_of`, its backward
compiled with it; :func:`~sgs_slam_core.kernels.adam.adam_update`), so its reference is that code run
eagerly; tests compare the two. Used with ``render.compile``: the ICP and the update on any backend
(on ``cpu`` in place of its C++ ICP, which is faster there), the mapping loss on the PyTorch ones
(``torch``, ``gsplat``; ``cpu`` keeps its C++ loss).

Each new shape compiles once (seconds per level on a GPU host, ten to twenty on two CPU cores), and
Inductor caches the result on disk for later processes. Where compiling fails (no C++ compiler, no
Triton) a warning says why and ``geometry.icp``'s PyTorch code runs from then on.
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Callable
from typing import Any

import torch
from torch import Tensor

from sgs_slam_core.errors import ShapeError
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.geometry.icp import (
    IcpKernels,
    IcpLevel,
    IcpSettings,
    torch_joint_step,
    torch_level,
    torch_step,
    torch_terms,
)
from sgs_slam_core.kernels.adam import adam_update
from sgs_slam_core.kernels.base import MappingKernels
from sgs_slam_core.kernels.losses import mapping_loss_of

__all__ = ["CompiledFunction", "compiled_icp_kernels", "compiled_mapping_kernels"]

log = logging.getLogger(__name__)

# Compiled variants kept per function: a pyramid's levels, with and without channels and weights,
# and more than one resolution in a process (Dynamo's default of 8 would run the rest eagerly).
# Floats (settings, learning rates) are constants of a run: specialised, each is a constant of the
# graph; left symbolic, every call would wrap each in a fresh tensor (a host-to-device copy on a GPU).
RECOMPILE_LIMIT = 64


class CompiledFunction:
    """``function`` compiled on first use, or run eagerly from the first compile failure on."""

    def __init__(
        self, function: Callable[..., Any], announce: Callable[[str], None] | None = None, dynamic: bool = False
    ) -> None:
        """``dynamic``: one graph for every size of the inputs (else one per size, each faster)."""
        self.function = function
        self.announce = announce or log.warning
        # Inductor's own use of a deprecated helper, once per lowered op: noise in a user's log
        warnings.filterwarnings("ignore", r"`torch\._prims_common\.check` is deprecated", FutureWarning)
        self.compiled = torch.compile(function, dynamic=dynamic)
        self.failed: str | None = None

    def __call__(self, *args: Any) -> Any:
        """``function(*args)``, compiled (a new graph for each new shape or constant)."""
        if self.failed is not None:
            return self.function(*args)
        try:
            with torch._dynamo.config.patch(recompile_limit=RECOMPILE_LIMIT, specialize_float=True):
                return self.compiled(*args)
        except torch._dynamo.exc.BackendCompilerFailed as error:
            inner = error.inner_exception
            first_line = (str(inner).strip().splitlines() or [""])[0]
            self.failed = f"{type(inner).__name__}: {first_line}"
            self.announce(f"torch.compile of {self.function.__name__} failed ({self.failed}); running it eagerly")
            return self.function(*args)


def compiled_icp_kernels(announce: Callable[[str], None] | None = None) -> IcpKernels:
    """The ICP's step, joint step, terms and reference level compiled by ``torch.compile`` (any device)."""
    step = CompiledFunction(torch_step, announce)
    level = CompiledFunction(torch_level, announce)

    def steps(
        src_to_ref: Tensor,  # [4, 4] float64
        points: Tensor,  # [N, 3] float32 source points, z = 0 where invalid
        values: Tensor | None,  # [N, C] float32 source channels
        weights: Tensor | None,  # [N] float32 depth-noise weights of the source points
        ref: IcpLevel,
        s: IcpSettings,
        count: int,
    ) -> Tensor:  # [4, 4] float64
        """``count`` compiled steps (a graph per step: unrolled into one, a level compiles twice as long)."""
        if values is not None and values.shape[1] != ref.num_channels:
            raise ShapeError(f"the reference level has {ref.num_channels} channels, the source {values.shape[1]}")
        for _ in range(count):
            src_to_ref = step(src_to_ref, points, values, weights, ref, s)
        return src_to_ref

    def level_rows(depth: Tensor, intrinsics: Intrinsics, min_normal_cos: float) -> Tensor:  # [H, W] -> [H * W, 7]
        return level(depth, intrinsics, min_normal_cos)

    # the observations' count changes with every frame: one graph for all counts
    joint = CompiledFunction(torch_joint_step, announce, dynamic=True)
    return IcpKernels(terms=CompiledFunction(torch_terms, announce), steps=steps, level=level_rows, joint=joint)


def compiled_mapping_kernels(announce: Callable[[str], None] | None = None) -> MappingKernels:
    """The mapping loss (forward and backward) and Adam's update compiled by ``torch.compile`` (any device)."""
    # the map's size changes with every window: one graph (per field) for every size
    update = CompiledFunction(adam_update, announce, dynamic=True)
    return MappingKernels(loss=CompiledFunction(mapping_loss_of, announce), update=update)
