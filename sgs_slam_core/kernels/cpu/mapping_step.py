"""A mapping step's gradients without autograd, every stage in the compiled CPU kernels.

Render (:func:`world_isotropic_forward`), the loss and its gradient with respect to the render
(:func:`mapping_loss_grads`), and the render's backward (:func:`world_isotropic_backward`), called in
order, give the gradients autograd gives through the same kernels, bit for bit (tested), without
building an autograd graph each step.
"""

from __future__ import annotations

import torch
from torch import Tensor

from sgs_slam_core.config.sections import MappingSettings
from sgs_slam_core.frame_data import FrameTensors
from sgs_slam_core.kernels.cpu.losses import mapping_loss_grads
from sgs_slam_core.kernels.cpu.render import world_isotropic_backward, world_isotropic_forward
from sgs_slam_core.profiling import stage
from sgs_slam_core.render.output import RenderOutput
from sgs_slam_core.render.settings import RenderSettings

__all__ = ["mapping_step_grads"]

_FIELDS = ("means", "log_scales", "logit_opacities", "colors")


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
        fields = (params["means"], params["log_scales"], params["logit_opacities"], params["colors"], sem)
        images, state = world_isotropic_forward(*fields, w2c, k, render_settings)
    depth = images.depth.view(k.height, k.width)
    out = RenderOutput(images.color, depth, images.silhouette, images.semantic, "cpu")
    with stage("map.loss"):
        total, g_color, g_sem, g_depth = mapping_loss_grads(out, data, s, semantic, weight, need_grad=True)
    with stage("map.backward"):
        grad_out = (g_color, g_sem, g_depth.view(k.height, k.width, 1), None)
        grads = world_isotropic_backward(state, grad_out, need_params=True, need_pose=False)
        for name, grad in zip(_FIELDS, grads[:4], strict=True):
            params[name].grad = grad
        sem_param = params["semantics"]
        sem_param.grad = grads[4] if semantic else (torch.zeros_like(sem_param) if window_semantic else None)
    return total
