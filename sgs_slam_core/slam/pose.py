"""Pose parameters optimised by tracking, and the constant-velocity motion model."""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from sgs_slam_core.geometry.se3 import se3_exp, so3_exp, so3_log

__all__ = ["PoseParameters", "predict_constant_velocity", "read_pose"]


def read_pose(pose: np.ndarray | Tensor, extra: Tensor | None) -> tuple[np.ndarray, np.ndarray | None]:
    """A pose [4, 4] left on the device and ``extra`` [K] values read back with it in one host read (float64).

    A pose already on the host is returned as it is, with nothing read unless ``extra`` is given.
    """
    if extra is None and isinstance(pose, np.ndarray):
        return pose, None
    device = pose.device if isinstance(pose, Tensor) else extra.device
    parts = [torch.as_tensor(pose, dtype=torch.float64, device=device).reshape(-1)]
    host = torch.cat(parts + ([] if extra is None else [extra.reshape(-1).double()])).cpu().numpy()
    return host[:16].reshape(4, 4), None if extra is None else host[16:]


class PoseParameters:
    """A world-to-camera pose as a camera-frame se(3) increment on a fixed start: w2c = Exp(xi) w2c0.

    ``xi = (rho, phi)``: ``rho`` translates the camera (m) and ``phi`` rotates it about its own centre
    (rad), so rotation and translation steps do not interfere (MonoGS's left perturbation). The
    reference optimised the raw w2c quaternion and translation instead, where a rotation step also
    moves the camera centre by |t| x angle; its quaternion learning rates correspond to twice the
    value here (a quaternion component step d rotates by 2d).
    """

    def __init__(self, w2c: np.ndarray, device: torch.device) -> None:
        self.start = torch.as_tensor(w2c, dtype=torch.float32, device=device)
        self.rho = torch.zeros(3, device=device, requires_grad=True)
        self.phi = torch.zeros(3, device=device, requires_grad=True)

    def w2c(self) -> Tensor:  # [4, 4], differentiable in rho and phi
        """The pose as a matrix."""
        return se3_exp(torch.cat([self.rho, self.phi])) @ self.start

    def xi(self) -> Tensor:  # [6] (rho, phi), detached
        """The current increment."""
        return torch.cat([self.rho, self.phi]).detach()

    def numpy(self, xi: Tensor | None = None) -> np.ndarray:  # [4, 4] float64
        """The pose at ``xi`` (default: the current value), composed in float64."""
        with torch.no_grad():
            xi = (self.xi() if xi is None else xi).double().cpu()
            return (se3_exp(xi) @ self.start.double().cpu()).numpy()


def predict_constant_velocity(
    c2w_prev: np.ndarray, c2w_prev2: np.ndarray | None, fraction: float = 1.0
) -> np.ndarray:  # [4, 4]
    """Next camera-to-world pose assuming the last relative motion repeats (identity motion without history).

    ``fraction``: the new frame's time gap over the last one (frames dropped in live mode); the
    motion is scaled by it (rotation angle and translation), 1 repeats it exactly.
    """
    if c2w_prev2 is None:
        return c2w_prev.copy()
    motion = np.linalg.inv(c2w_prev2) @ c2w_prev
    if abs(fraction - 1.0) > 1e-9:
        omega = so3_log(torch.from_numpy(motion[:3, :3].copy()))
        motion[:3, :3] = so3_exp(omega * fraction).numpy()
        motion[:3, 3] *= fraction
    pred = c2w_prev @ motion
    u, _, vt = np.linalg.svd(pred[:3, :3])  # keep the rotation orthonormal
    pred[:3, :3] = u @ vt
    return pred
