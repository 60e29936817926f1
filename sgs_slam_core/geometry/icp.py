"""Projective point-to-plane ICP between two depth images, coarse to fine (as KinectFusion).

Tracking uses it to refine the motion prediction before its photometric steps. Adam moves the
pose by about its learning rate per step, so a prediction that is off by a few frames' motion
(frames dropped by a live camera, a jerk) takes more steps than the budget; a few Gauss-Newton
steps on depth close most of that gap for about the cost of one photometric step.

Written here rather than taken from a library: Open3D's RGB-D odometry is not among the
dependencies and works on host arrays, while this runs on the caller's device with no host read
until the end. Every step has a fixed shape (invalid pixels get zero weight), so nothing here
waits for the GPU.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from sgs_slam_core.errors import ShapeError
from sgs_slam_core.geometry.camera import Intrinsics, vertex_map
from sgs_slam_core.geometry.se3 import se3_exp

__all__ = ["IcpLevel", "IcpResult", "IcpSettings", "align_depth", "icp_pyramid"]

_MIN_NORMAL_COS = 0.1  # a normal at more than ~84 degrees to its viewing ray spans a depth edge


@dataclass(frozen=True)
class IcpSettings:
    """Projective point-to-plane ICP.

    Attributes:
        iterations: Gauss-Newton steps per pyramid level, coarsest first; the last level is the
            full image, each one before it half the size of the next.
        max_distance_m: correspondences farther apart than this (m) are left out.
        huber_m: residuals beyond this (m) are down-weighted (Huber).
        damping: Levenberg damping, relative to the mean diagonal of the normal matrix; keeps the
            directions the geometry does not constrain (a single wall) at the prediction.
        min_width: coarse levels narrower than this (pixels) are left out, with their steps (on the
            64x48 test scene a 16x12 level made the result worse than the prediction).
    """

    iterations: tuple[int, ...] = (6, 4, 3)
    max_distance_m: float = 0.1
    huber_m: float = 0.01
    damping: float = 1e-4
    min_width: int = 40

    def steps_for(self, width: int) -> tuple[int, ...]:
        """Steps per level, coarsest first, for an image ``width`` pixels wide (the full image always)."""
        steps = self.iterations
        while len(steps) > 1 and width / 2 ** (len(steps) - 1) < self.min_width:
            steps = steps[1:]
        return steps


@dataclass(frozen=True)
class IcpLevel:
    """One pyramid level of the reference depth image, packed for one gather per step."""

    intrinsics: Intrinsics
    packed: Tensor  # [H * W, 7] float32: camera-frame vertex (m), unit normal facing the camera, valid (0/1)

    @property
    def vertices(self) -> Tensor:  # [H, W, 3]
        """Camera-frame points (m), 0 where the depth is invalid."""
        return self.packed[:, :3].reshape(*self.intrinsics.shape, 3)

    @property
    def normals(self) -> Tensor:  # [H, W, 3]
        """Unit normals facing the camera, 0 where undefined."""
        return self.packed[:, 3:6].reshape(*self.intrinsics.shape, 3)

    @property
    def valid(self) -> Tensor:  # [H, W] bool
        """Pixels whose vertex and normal are defined."""
        return self.packed[:, 6].reshape(self.intrinsics.shape) > 0


@dataclass(frozen=True)
class IcpResult:
    """The aligned pose and how well the two depth images agree at it."""

    src_to_ref: Tensor  # [4, 4] float64: source camera frame -> reference camera frame
    inlier_fraction: float  # source pixels with a correspondence at the result, over source pixels with depth
    rms_m: float  # RMS point-to-plane residual over those correspondences (m)


def _half(intrinsics: Intrinsics) -> Intrinsics:
    """Intrinsics of ``image[::2, ::2]`` (pixel u there is pixel 2u here)."""
    k = intrinsics
    return Intrinsics(k.fx / 2, k.fy / 2, k.cx / 2, k.cy / 2, (k.width + 1) // 2, (k.height + 1) // 2)


def _level(depth: Tensor, intrinsics: Intrinsics) -> IcpLevel:  # depth [H, W] m
    vertices = vertex_map(depth, intrinsics)
    valid = vertices[..., 2] > 0
    # central differences inside a one-pixel border; every neighbour must be valid
    dx = vertices[1:-1, 2:] - vertices[1:-1, :-2]
    dy = vertices[2:, 1:-1] - vertices[:-2, 1:-1]
    n = torch.linalg.cross(dx, dy)
    n = n / n.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    centre = vertices[1:-1, 1:-1]
    cos = (n * centre).sum(-1) / centre.norm(dim=-1).clamp_min(1e-12)
    inner = valid[1:-1, 1:-1] & valid[1:-1, 2:] & valid[1:-1, :-2] & valid[2:, 1:-1] & valid[:-2, 1:-1]
    inner &= cos.abs() > _MIN_NORMAL_COS
    n = torch.where(inner[..., None], n * -torch.sign(cos)[..., None], 0.0)  # towards the camera
    packed = torch.zeros((*intrinsics.shape, 7), dtype=torch.float32, device=depth.device)
    packed[..., :3] = vertices
    packed[1:-1, 1:-1, 3:6] = n
    packed[1:-1, 1:-1, 6] = inner.float()
    return IcpLevel(intrinsics, packed.reshape(-1, 7))


def _scales(depth: Tensor, intrinsics: Intrinsics, levels: int) -> list[tuple[Tensor, Intrinsics]]:
    """``depth`` subsampled by 2 per level, coarsest first."""
    if depth.shape != intrinsics.shape:
        raise ShapeError(f"depth is {tuple(depth.shape)} but intrinsics are {intrinsics.shape}")
    if levels < 1:
        raise ShapeError(f"an ICP pyramid needs at least one level, got {levels}")
    out = [(depth, intrinsics)]
    for _ in range(levels - 1):
        depth, intrinsics = depth[::2, ::2], _half(intrinsics)
        out.append((depth, intrinsics))
    return out[::-1]


def icp_pyramid(depth: Tensor, intrinsics: Intrinsics, levels: int) -> list[IcpLevel]:  # depth [H, W] m, 0 = invalid
    """Vertex and normal maps of ``depth`` at ``levels`` scales, coarsest first (the reference side).

    ``levels`` is ``len(settings.steps_for(width))``.
    """
    return [_level(d, k) for d, k in _scales(depth, intrinsics, levels)]


def _correspondences(
    src_to_ref: Tensor,  # [4, 4] float64
    src: Tensor,  # [N, 3] camera-frame points of the source level, z = 0 where invalid
    ref: IcpLevel,
    max_distance_m: float,
) -> tuple[Tensor, Tensor, Tensor, Tensor]:  # points [N, 3], normals [N, 3], residuals [N], inliers [N] bool
    """Source points in the reference frame, the reference normal and residual at their projections."""
    rot, trans = src_to_ref[:3, :3].float(), src_to_ref[:3, 3].float()
    p = src @ rot.T + trans
    k = ref.intrinsics
    z = p[:, 2].clamp_min(1e-6)
    u = torch.floor(p[:, 0] / z * k.fx + (k.cx + 0.5))  # nearest pixel (floor: torch.round is 30x slower on the CPU)
    v = torch.floor(p[:, 1] / z * k.fy + (k.cy + 0.5))
    inside = (src[:, 2] > 0) & (p[:, 2] > 1e-6) & (u >= 0) & (u <= k.width - 1) & (v >= 0) & (v <= k.height - 1)
    index = torch.where(inside, v * k.width + u, 0.0).long()
    target = ref.packed.index_select(0, index)  # [N, 7]
    n = target[:, 3:6]
    diff = p - target[:, :3]
    inliers = inside & (target[:, 6] > 0) & (diff.square().sum(-1) < max_distance_m**2)
    return p, n, (diff * n).sum(-1), inliers


def _gauss_newton_step(
    src_to_ref: Tensor, src: Tensor, ref: IcpLevel, s: IcpSettings
) -> Tensor:  # src_to_ref [4, 4] float64, src [N, 3] -> the updated pose [4, 4]
    p, n, r, inliers = _correspondences(src_to_ref, src, ref, s.max_distance_m)
    weight = torch.where(inliers, (s.huber_m / r.abs().clamp_min(1e-12)).clamp(max=1.0), 0.0)
    # rows [d r / d (rho, phi) | r] for a left perturbation; one product gives J^T W J and J^T W r
    rows = torch.cat([n, torch.linalg.cross(p, n), r[:, None]], dim=-1)  # [N, 7]
    normal = ((rows * weight[:, None]).T @ rows).double()  # [7, 7]
    hessian, gradient = normal[:6, :6], normal[:6, 6]
    eye = torch.eye(6, dtype=torch.float64, device=hessian.device)
    hessian = hessian + (s.damping * hessian.diagonal().mean() + 1e-12) * eye
    xi = -torch.linalg.solve_ex(hessian, gradient)[0]  # solve_ex: no error check, so no wait for the GPU
    return se3_exp(xi) @ src_to_ref


def _truncated_cost(r: Tensor, inliers: Tensor, valid: Tensor, s: IcpSettings) -> Tensor:  # [] float64
    """Sum over valid source points of min(r^2, (3 huber_m)^2), points without a match counting the cap.

    Comparable between poses, unlike the inlier RMS: a pose that loses hard points does not gain.
    """
    cap = (3 * s.huber_m) ** 2
    return torch.where(inliers, r.double().square().clamp(max=cap), cap * valid.double()).sum()


def align_depth(
    depth: Tensor,  # [H, W] m, 0 = invalid: the source (new) frame
    intrinsics: Intrinsics,
    reference: list[IcpLevel],  # icp_pyramid of the reference frame, same intrinsics and level count
    init_src_to_ref: Tensor,  # [4, 4] float64
    s: IcpSettings,
) -> IcpResult:
    """Refine ``init_src_to_ref`` so the source depth lies on the reference surface (one host read)."""
    iterations = s.steps_for(intrinsics.width)
    if len(reference) != len(iterations):
        raise ShapeError(f"reference pyramid has {len(reference)} levels, settings ask for {len(iterations)}")
    init = pose = init_src_to_ref.to(device=depth.device, dtype=torch.float64)
    points = []
    for (d, k), ref, steps in zip(_scales(depth, intrinsics, len(iterations)), reference, iterations, strict=True):
        if k.shape != ref.intrinsics.shape:
            raise ShapeError(f"source level is {k.shape}, reference level {ref.intrinsics.shape}")
        points.append(vertex_map(d, k).reshape(-1, 3))
        for _ in range(steps):
            pose = _gauss_newton_step(pose, points[-1], ref, s)
    valid_source = points[-1][:, 2] > 0
    # Never worse than the start at full resolution: on a view with a weakly constrained direction
    # the 40x30 level's association can move a right start centimetres away (room frames 172-175,
    # BENCHMARKS.md), and the finer levels do not bring it back.
    _, _, r0, inliers0 = _correspondences(init, points[-1], reference[-1], s.max_distance_m)
    _, _, r, inliers = _correspondences(pose, points[-1], reference[-1], s.max_distance_m)
    worse = _truncated_cost(r, inliers, valid_source, s) > _truncated_cost(r0, inliers0, valid_source, s)
    pose, r, inliers = torch.where(worse, init, pose), torch.where(worse, r0, r), torch.where(worse, inliers0, inliers)
    stats = torch.stack([inliers.sum().double(), (r.double().square() * inliers).sum(), valid_source.sum().double()])
    count_f, sq_f, total_f = stats.tolist()
    rms = (sq_f / count_f) ** 0.5 if count_f > 0 else float("inf")
    return IcpResult(pose, count_f / total_f if total_f > 0 else 0.0, rms)
