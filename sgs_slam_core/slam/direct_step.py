"""A mapping step's gradients without autograd, where every piece has a fused CPU form.

With an isotropic map on the compiled CPU backend and the fused loss, a mapping step is three C++
stages: render (``cpu_backend.world_isotropic_forward``), loss and its gradient with respect to the
render (``losses.mapping_loss_and_grads``), and the render's backward
(``cpu_backend.world_isotropic_backward``). Calling them in order gives the gradients autograd
gives through the same kernels, bit for bit (tested), without the autograd graph: two Python
function nodes, five gradient accumulations and the engine's own work cost ~0.8 ms of a 7.8 ms
step on the TUM map at 160x120, measured on a loaded 2-core machine (BENCHMARKS.md, issue 16,
fifth stop). Elsewhere (CUDA, anisotropic maps, no
compiler) ``mapper.map_window`` takes the autograd path.
"""

from __future__ import annotations

import torch
from torch import Tensor

from sgs_slam_core.config.sections import MappingSettings
from sgs_slam_core.profiling import stage
from sgs_slam_core.render import cpu_backend
from sgs_slam_core.render.api import RenderOutput, resolve_backend
from sgs_slam_core.render.settings import RenderSettings
from sgs_slam_core.slam.frame_data import FrameTensors
from sgs_slam_core.slam.fused_losses import fused_available
from sgs_slam_core.slam.losses import mapping_loss_and_grads

__all__ = ["direct_available", "mapping_step_grads"]

_FIELDS = ("means", "log_scales", "logit_opacities", "colors", "semantics")


def direct_available(isotropic: bool, device: torch.device, render_settings: RenderSettings) -> bool:
    """True where :func:`mapping_step_grads` runs: isotropic map, compiled CPU backend, fused loss."""
    return isotropic and resolve_backend(render_settings.backend, device) == "cpu" and fused_available(device)


def mapping_step_grads(
    params: dict[str, Tensor],  # the optimiser's leaves: means [N, 3], log_scales [N, 1], ... semantics [N, S]
    data: FrameTensors,
    w2c: Tensor,  # [4, 4] on the map's device
    s: MappingSettings,
    render_settings: RenderSettings,
    semantic: bool,
    weight: float,
    window_semantic: bool = True,
) -> Tensor:  # [] the loss
    """Set each parameter's ``.grad`` to the gradient of ``weight`` x the mapping loss of ``data`` seen from ``w2c``.

    As ``render`` + ``mapping_loss`` + ``backward()`` would, including a zero gradient for the
    semantic features when they are not rendered (``semantic`` False). With ``window_semantic``
    False (no step of this optimiser renders them) they get no gradient instead: a fresh Adam's
    zero moments leave them exactly as zero gradients would, without the zeros and their update.
    """
    k = data.intrinsics
    w2c = w2c.to(device=params["means"].device, dtype=params["means"].dtype)
    sem = params["semantics"] if semantic else params["semantics"][:, :0]
    with stage("map.render"):
        (color, sem_img, depth, sil), state = cpu_backend.world_isotropic_forward(
            params["means"], params["log_scales"], params["logit_opacities"], params["colors"], sem, w2c, k,
            render_settings,
        )  # fmt: skip
    out = RenderOutput(color, depth.view(k.height, k.width), sil, sem_img, "cpu")
    with stage("map.loss"):
        total, g_color, g_sem, g_depth = mapping_loss_and_grads(out, data, s, semantic, weight)
    with stage("map.backward"):
        grads = cpu_backend.world_isotropic_backward(
            state, (g_color, g_sem, g_depth.view(k.height, k.width, 1), None), need_params=True, need_pose=False
        )
        for name, grad in zip(_FIELDS[:4], grads[:4], strict=True):
            params[name].grad = grad
        sem_param = params["semantics"]
        sem_param.grad = grads[4] if semantic else (torch.zeros_like(sem_param) if window_semantic else None)
    return total
