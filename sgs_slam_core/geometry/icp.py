"""Projective point-to-plane ICP between two RGB-D images, coarse to fine (as KinectFusion).

Optional photometric channels (intensity, semantics) join the depth term through their image
gradients. Two users: the motion model refines its prediction by depth ICP against the last tracked frame,
and the Gauss-Newton tracker aligns a frame to the map rendered at the prediction (depth, colour
and semantics), so the pose moves by a Gauss-Newton step rather than by a learning rate.

Written here rather than taken from a library: Open3D's RGB-D odometry is not among the
dependencies and works on host arrays, while this runs on the caller's device with no host read
until the end. Every step has a fixed shape (invalid pixels get zero weight), so nothing here
waits for the GPU.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple, Protocol

import torch
import torch.nn.functional as nn_f
from torch import Tensor

from sgs_slam_core.errors import ShapeError
from sgs_slam_core.geometry.camera import Intrinsics, vertex_map
from sgs_slam_core.geometry.depth_noise import DepthNoise
from sgs_slam_core.geometry.products import fusable_matmul
from sgs_slam_core.geometry.se3 import se3_exp

__all__ = [
    "IcpJoint",
    "IcpKernels",
    "IcpLevel",
    "IcpLevelKernel",
    "IcpResult",
    "IcpSettings",
    "IcpSteps",
    "IcpTerms",
    "Observations",
    "align_depth",
    "align_device",
    "channel_pyramid",
    "icp_pyramid",
    "refine_device",
    "source_channels",
    "torch_joint_step",
    "torch_level",
    "torch_step",
    "torch_terms",
]


class IcpTerms(Protocol):
    """One Gauss-Newton step's normal equations and cost in one call (a compiled form of this module's step)."""

    def __call__(
        self,
        src_to_ref: Tensor,  # [4, 4] float64
        points: Tensor,  # [N, 3] float32 source points, z = 0 where invalid
        values: Tensor | None,  # [N, C] float32 source channels
        packed: Tensor,  # [H * W, 7 (+ 3C + 1)] the reference level's rows
        intrinsics: Intrinsics,  # the reference level's camera
        max_distance_m: float,
        huber_m: float,
        weights: Tensor | None,  # [N] float32 depth-noise weights of the source points
    ) -> Tensor:  # [53] float64: normal matrix [49], truncated cost, correspondences, their sum r^2, source points
        """The terms at ``src_to_ref``."""
        ...


class IcpSteps(Protocol):
    """A level's Gauss-Newton steps in one call (a compiled form of this module's step loop)."""

    def __call__(
        self,
        src_to_ref: Tensor,  # [4, 4] float64
        points: Tensor,  # [N, 3] float32 source points, z = 0 where invalid
        values: Tensor | None,  # [N, C] float32 source channels
        weights: Tensor | None,  # [N] float32 depth-noise weights of the source points
        ref: IcpLevel,
        s: IcpSettings,
        steps: int,
    ) -> Tensor:  # [4, 4] float64
        """The pose after ``steps`` damped Gauss-Newton updates against ``ref``."""
        ...


class IcpJoint(Protocol):
    """The finest level's joint step with sparse observations in one call (a compiled form of it)."""

    def __call__(
        self,
        src_to_ref: Tensor,  # [4, 4] float64
        points: Tensor,  # [N, 3] float32 source points, z = 0 where invalid
        values: Tensor | None,  # [N, C] float32 source channels
        weights: Tensor | None,  # [N] float32 depth-noise weights of the source points
        ref: IcpLevel,
        s: IcpSettings,
        observations: Observations,
    ) -> Tensor:  # [4, 4] float64
        """The pose after one damped step of the dense terms and the observations' together."""
        ...


class IcpLevelKernel(Protocol):
    """One reference level's packed rows in one call (a compiled form of this module's ``_level``)."""

    def __call__(self, depth: Tensor, intrinsics: Intrinsics, min_normal_cos: float) -> Tensor:
        """``depth`` [H, W] m, 0 = invalid -> [H * W, 7] rows as :attr:`IcpLevel.packed`."""
        ...


@dataclass(frozen=True)
class IcpKernels:
    """Compiled forms of this module's per-step and per-level work; None where its PyTorch code runs."""

    terms: IcpTerms | None = None
    steps: IcpSteps | None = None
    level: IcpLevelKernel | None = None
    joint: IcpJoint | None = None


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
        depth_noise: the source camera's depth noise; each point-to-plane residual and its row are
            then weighed by the noise at the source level's median depth over the noise at the
            point's depth (:meth:`DepthNoise.weights`), so ``huber_m`` and the costs are metres at
            that depth. None: every point weighs the same.
    """

    iterations: tuple[int, ...] = (6, 4, 3)
    max_distance_m: float = 0.1
    huber_m: float = 0.01
    damping: float = 1e-4
    min_width: int = 40
    depth_noise: DepthNoise | None = None

    def steps_for(self, width: int) -> tuple[int, ...]:
        """Steps per level, coarsest first, for an image ``width`` pixels wide (the full image always)."""
        steps = self.iterations
        while len(steps) > 1 and width / 2 ** (len(steps) - 1) < self.min_width:
            steps = steps[1:]
        return steps


@dataclass(frozen=True)
class IcpLevel:
    """One pyramid level of the reference image, packed for one gather per step."""

    intrinsics: Intrinsics
    # [H * W, 7 + 3C + 1] float32: camera-frame vertex (m), unit normal facing the camera, valid (0/1);
    # then, with C photometric channels, their values, d/du, d/dv and their own valid (0/1)
    packed: Tensor
    num_channels: int = 0

    def with_channels(self, channels: Tensor) -> IcpLevel:  # [1, 3C + 1, H, W] from channel_pyramid
        """This level with photometric channels appended to its rows."""
        if self.num_channels:
            raise ShapeError("the level has channels already")
        rows = channels[0].flatten(1).T.to(self.packed.dtype)  # [H * W, 3C + 1]
        if rows.shape[0] != self.packed.shape[0]:
            raise ShapeError(f"channels have {rows.shape[0]} pixels, the level {self.packed.shape[0]}")
        return IcpLevel(self.intrinsics, torch.cat([self.packed, rows], dim=1), (rows.shape[1] - 1) // 3)

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

    src_to_ref: Tensor  # [4, 4] float64 on the host: source camera frame -> reference camera frame
    inlier_fraction: float  # source pixels with a correspondence at the result, over source pixels with depth
    rms_m: float  # RMS point-to-plane residual over those correspondences (m)


@dataclass(frozen=True)
class Observations:
    """Points of known position seen at pixels of the source frame: sparse feature matches.

    After the finest level's steps, one more step solves the dense terms and the points'
    reprojection terms together (near the dense optimum the dense cost is close to its quadratic
    model, so one Gauss-Newton step reaches the joint optimum). A pixel of reprojection
    error counts as the lateral displacement it means at the point's depth (m), and each point as
    ``weight`` pixels of the dense terms: the dense terms decide where they are well conditioned,
    the points where the geometry leaves a direction free (a camera over a plane slides along it).
    """

    points: Tensor  # [M, 3] float64, in the reference (rendered) camera's frame (m)
    pixels: Tensor  # [M, 2] float64, where the source frame sees them (px, u v)
    weight: float  # how many dense pixels one point weighs as
    huber_px: float  # reprojection errors beyond this (px) are down-weighted

    def __post_init__(self) -> None:
        if self.points.shape[-1] != 3 or self.pixels.shape != (self.points.shape[0], 2):
            raise ShapeError(
                f"observations need [M, 3] points and [M, 2] pixels, got {self.points.shape}, {self.pixels.shape}"
            )


def _observation_rows(
    src_to_ref: Tensor,  # [4, 4] float64
    obs: Observations,
    k: Intrinsics,  # the source camera (the finest level)
) -> tuple[Tensor, Tensor]:  # rows [2M, 7] float64 [d r / d (rho, phi) | r] in metres, their Huber weights [2M]
    """The points' reprojection rows for a left perturbation of ``src_to_ref``, scaled to metres.

    With x = R y + t the point in the source camera (``R, t`` of the inverse pose) and g the
    gradient of a pixel coordinate in x, the row is ``[-g R | (g R) x y]``: x(xi) = R Exp(-xi) y + t.
    """
    inverse = torch.linalg.inv(src_to_ref)
    rot, y = inverse[:3, :3], obs.points
    x = y @ rot.T + inverse[:3, 3]  # [M, 3] in the source camera
    ahead = x[:, 2] > 1e-3
    inv_z = 1.0 / torch.where(ahead, x[:, 2], 1.0)  # [M]
    r = torch.stack([x[:, 0] * inv_z * k.fx + k.cx, x[:, 1] * inv_z * k.fy + k.cy], dim=-1) - obs.pixels  # [M, 2] px
    # d u / d x = fx / z (1, 0, -x / z) and d v / d x = fy / z (0, 1, -y / z), then through R
    gu = (k.fx * inv_z)[:, None] * (rot[0] - (x[:, 0] * inv_z)[:, None] * rot[2])  # [M, 3]
    gv = (k.fy * inv_z)[:, None] * (rot[1] - (x[:, 1] * inv_z)[:, None] * rot[2])
    g = torch.stack([gu, gv], dim=1)  # [M, 2, 3]
    jac = torch.cat([-g, torch.linalg.cross(g, y[:, None].expand_as(g), dim=-1)], dim=-1)  # [M, 2, 6] px
    metres = (obs.weight**0.5) * 2.0 / ((k.fx + k.fy) * inv_z)  # [M] a pixel's lateral metres at the depth, weighed
    rows = torch.cat([jac, r[..., None]], dim=-1) * metres[:, None, None]  # [M, 2, 7]
    huber = torch.where(ahead[:, None], (obs.huber_px / r.abs().clamp_min(1e-12)).clamp(max=1.0), 0.0)
    return rows.reshape(-1, 7), huber.reshape(-1)


def _observation_normal(src_to_ref: Tensor, obs: Observations, k: Intrinsics) -> Tensor:  # [7, 7] float64
    """``[J^T W J | J^T W r]`` of the points' Huber-weighted reprojection rows."""
    rows, weight = _observation_rows(src_to_ref, obs, k)
    return (rows * weight[:, None]).T @ rows


def _half(intrinsics: Intrinsics) -> Intrinsics:
    """Intrinsics of ``image[::2, ::2]`` (pixel u there is pixel 2u here)."""
    k = intrinsics
    return Intrinsics(k.fx / 2, k.fy / 2, k.cx / 2, k.cy / 2, (k.width + 1) // 2, (k.height + 1) // 2)


def _level(depth: Tensor, intrinsics: Intrinsics, min_normal_cos: float = _MIN_NORMAL_COS) -> IcpLevel:  # [H, W] m
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
    inner &= cos.abs() > min_normal_cos
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
    cameras = _level_intrinsics(intrinsics, levels)
    return [(depth[:: 2**i, :: 2**i], k) for i, k in zip(reversed(range(levels)), cameras, strict=True)]


def _level_intrinsics(intrinsics: Intrinsics, levels: int) -> list[Intrinsics]:
    """The intrinsics of ``levels`` pyramid levels, each half the next, coarsest first."""
    out = [intrinsics]
    for _ in range(levels - 1):
        out.append(_half(out[-1]))
    return out[::-1]


def _source_points(vertices: Tensor, levels: int) -> list[Tensor]:  # [H, W, 3] -> per level [h * w, 3]
    """The source's points at each of ``levels`` pyramid levels, coarsest first.

    Subsampling the full-size vertex map gives each coarse level's vertex map bit for bit (halving
    the focal length and centre is exact), at one map's cost instead of one per level.
    """
    return [vertices[:: 2**i, :: 2**i].reshape(-1, 3) for i in reversed(range(levels))]


def icp_pyramid(
    depth: Tensor,  # [H, W] m, 0 = invalid
    intrinsics: Intrinsics,
    levels: int,
    kernel: IcpLevelKernel | None = None,  # the kernels' compiled level (``IcpKernels.level``), else PyTorch's
) -> list[IcpLevel]:
    """Vertex and normal maps of ``depth`` at ``levels`` scales, coarsest first (the reference side).

    ``levels`` is ``len(settings.steps_for(width))``.
    """
    if kernel is None:
        return [_level(d, k) for d, k in _scales(depth, intrinsics, levels)]
    return [IcpLevel(k, kernel(d, k, _MIN_NORMAL_COS)) for d, k in _scales(depth, intrinsics, levels)]


def torch_level(depth: Tensor, intrinsics: Intrinsics, min_normal_cos: float) -> Tensor:  # [H, W] m -> [H * W, 7]
    """:class:`IcpLevelKernel` in PyTorch: one reference level's packed rows (what ``icp_pyramid`` builds)."""
    return _level(depth, intrinsics, min_normal_cos).packed


def _blur(image: Tensor) -> Tensor:  # [1, C, H, W] -> [1, C, H, W]
    """3x3 binomial blur (edges replicated), so a coarse level does not alias the fine one.

    Written as shifted sums: on the CPU they take a fraction of a depthwise convolution's time.
    """
    x = nn_f.pad(image, (1, 1, 1, 1), mode="replicate")
    x = (x[..., :-2, :] + 2 * x[..., 1:-1, :] + x[..., 2:, :]) * 0.25
    return (x[..., :-2] + 2 * x[..., 1:-1] + x[..., 2:]) * 0.25


def _erode(mask: Tensor) -> Tensor:  # [1, 1, H, W] float 0/1 -> [1, 1, H, W]
    """1 where the pixel and its in-image 8 neighbours are 1.

    Separable minima of shifted views: on the CPU a fifth of ``max_pool2d``'s time at 160x120.
    """
    x = nn_f.pad(mask, (1, 1, 1, 1), value=1.0)
    x = torch.minimum(torch.minimum(x[..., :-2, :], x[..., 1:-1, :]), x[..., 2:, :])
    return torch.minimum(torch.minimum(x[..., :-2], x[..., 1:-1]), x[..., 2:])


def _channel_levels(image: Tensor, levels: int) -> list[Tensor]:  # [H, W, C] -> [1, C, h, w] coarsest first
    out = [image.permute(2, 0, 1)[None]]
    for _ in range(levels - 1):
        out.append(_blur(out[-1])[..., ::2, ::2])
    return out[::-1]


def channel_pyramid(
    image: Tensor,  # [H, W, C] reference channels, in the units their residuals weigh as (m)
    valid: Tensor,  # [H, W] bool, where the channels are trusted
    levels: int,
) -> list[Tensor]:  # per level, coarsest first: [1, 3C + 1, h, w]
    """The reference side's channels for :meth:`IcpLevel.with_channels`, subsampled as :func:`icp_pyramid`.

    Each level holds the channels, their central differences along u and v, and a validity that
    also requires every pixel the blur and the differences touched to be valid.
    """
    if image.shape[:2] != valid.shape:
        raise ShapeError(f"channels are {tuple(image.shape)} but the mask is {tuple(valid.shape)}")
    masks = [valid[None, None].to(image.dtype)]
    for _ in range(levels - 1):
        masks.append(_erode(masks[-1])[..., ::2, ::2])
    out = []
    for img, mask in zip(_channel_levels(image, levels), masks[::-1], strict=True):
        du = torch.zeros_like(img)
        dv = torch.zeros_like(img)
        du[..., 1:-1] = (img[..., 2:] - img[..., :-2]) * 0.5
        dv[..., 1:-1, :] = (img[..., 2:, :] - img[..., :-2, :]) * 0.5
        ok = _erode(mask)
        ok[..., 0, :] = ok[..., -1, :] = 0.0
        ok[..., :, 0] = ok[..., :, -1] = 0.0
        out.append(torch.cat([img, du, dv, ok], dim=1))
    return out


def source_channels(image: Tensor, levels: int) -> list[Tensor]:  # [H, W, C] -> per level [h * w, C]
    """The source frame's channels at the pyramid's levels, coarsest first, one row per pixel."""
    return [lvl[0].flatten(1).T.contiguous() for lvl in _channel_levels(image, levels)]


@dataclass(frozen=True)
class _Association:
    """Source points projected into the reference level (projective association, nearest pixel)."""

    points: Tensor  # [N, 3] source points in the reference camera frame
    target: Tensor  # [N, 7 + 3C + 1] the reference row at each projection
    offset: Tensor | None  # [N, 2] projection minus the nearest pixel centre (pixels), with channels only
    residual: Tensor  # [N] point-to-plane residual (m)
    inliers: Tensor  # [N] bool
    weight: Tensor | None  # [N] the depth-noise weight of each point's residual and row; None = 1

    @property
    def weighted(self) -> Tensor:  # [N]
        """The point-to-plane residuals the alignment minimises (times their depth-noise weights)."""
        return self.residual if self.weight is None else self.residual * self.weight


def _associate(
    src_to_ref: Tensor,  # [4, 4] float64
    src: Tensor,  # [N, 3] camera-frame points of the source level, z = 0 where invalid
    ref: IcpLevel,
    max_distance_m: float,
    weight: Tensor | None = None,  # [N] the source points' depth-noise weights
) -> _Association:
    rot, trans = src_to_ref[:3, :3].float(), src_to_ref[:3, 3].float()
    p = fusable_matmul(src, rot.T) + trans
    k = ref.intrinsics
    z = p[:, 2].clamp_min(1e-6)
    uc, vc = p[:, 0] / z * k.fx, p[:, 1] / z * k.fy
    u = torch.floor(uc + (k.cx + 0.5))  # nearest pixel (floor: torch.round is 30x slower on the CPU)
    v = torch.floor(vc + (k.cy + 0.5))
    inside = (src[:, 2] > 0) & (p[:, 2] > 1e-6) & (u >= 0) & (u <= k.width - 1) & (v >= 0) & (v <= k.height - 1)
    index = torch.where(inside, v * k.width + u, 0.0).long()
    target = ref.packed.index_select(0, index)  # [N, 7 (+ 3C + 1)]
    n = target[:, 3:6]
    diff = p - target[:, :3]
    inliers = inside & (target[:, 6] > 0) & (diff.square().sum(-1) < max_distance_m**2)
    offset = torch.stack([uc + k.cx - u, vc + k.cy - v], dim=-1) if ref.num_channels else None
    return _Association(p, target, offset, (diff * n).sum(-1), inliers, weight)


def _correspondences(
    src_to_ref: Tensor,  # [4, 4] float64
    src: Tensor,  # [N, 3] camera-frame points of the source level, z = 0 where invalid
    ref: IcpLevel,
    max_distance_m: float,
) -> tuple[Tensor, Tensor, Tensor, Tensor]:  # points [N, 3], normals [N, 3], residuals [N], inliers [N] bool
    """Source points in the reference frame, the reference normal and residual at their projections."""
    a = _associate(src_to_ref, src, ref, max_distance_m)
    return a.points, a.target[:, 3:6], a.residual, a.inliers


def _channel_rows(
    a: _Association,
    values: Tensor,  # [N, C] source channels
    ref: IcpLevel,
    intrinsics: Intrinsics,
) -> tuple[Tensor, Tensor, Tensor]:  # rows [N, C, 6] d r / d (rho, phi), residuals [N, C], usable [N, C] bool
    """Reference channels at the projections minus the source's, and their Jacobians.

    The reference value is the nearest pixel's plus its gradient times the sub-pixel offset (exact
    for a locally linear image), which needs no second gather.
    """
    c = ref.num_channels
    if a.offset is None or values.shape[1] != c:
        raise ShapeError(f"the reference level has {c} channels, the source {values.shape[1]}")
    k, p, t = intrinsics, a.points, a.target
    gu, gv = t[:, 7 + c : 7 + 2 * c], t[:, 7 + 2 * c : 7 + 3 * c]  # [N, C]
    r = t[:, 7 : 7 + c] + gu * a.offset[:, :1] + gv * a.offset[:, 1:] - values
    inv_z = 1.0 / p[:, 2:].clamp_min(1e-6)  # [N, 1]
    ju, jv = gu * (k.fx * inv_z), gv * (k.fy * inv_z)  # [N, C]: d r / d x, d r / d y
    jz = -(ju * p[:, :1] + jv * p[:, 1:2]) * inv_z  # d r / d z
    jp = torch.stack([ju, jv, jz], dim=-1)  # [N, C, 3]
    rows = torch.cat([jp, torch.linalg.cross(p[:, None].expand_as(jp), jp)], dim=-1)
    usable = (a.inliers & (t[:, 7 + 3 * c] > 0))[:, None].expand(-1, c)
    return rows, r, usable


def _huber_weight(r: Tensor, usable: Tensor, huber_m: float) -> Tensor:
    return torch.where(usable, (huber_m / r.abs().clamp_min(1e-12)).clamp(max=1.0), 0.0)


class _LevelSource(NamedTuple):
    """What one pyramid level aligns onto its reference."""

    points: Tensor  # [N, 3] camera frame, z = 0 where invalid
    values: Tensor | None = None  # [N, C] channels (None: depth alone)
    weights: Tensor | None = None  # [N] depth-noise weights (None: every point the same)


def _gauss_newton_step(
    src_to_ref: Tensor, source: _LevelSource, ref: IcpLevel, s: IcpSettings
) -> Tensor:  # src_to_ref [4, 4] float64 -> the updated pose [4, 4]
    return _solve(_normal_matrix(src_to_ref, source, ref, s), src_to_ref, s)


def _normal_matrix(
    src_to_ref: Tensor,  # [4, 4] float64
    source: _LevelSource,
    ref: IcpLevel,
    s: IcpSettings,
    association: _Association | None = None,  # the source's at ``src_to_ref``, where the caller has it already
) -> Tensor:  # [7, 7] float64: [J^T W J | J^T W r] of the Huber-weighted rows
    values = source.values
    a = association or _associate(src_to_ref, source.points, ref, s.max_distance_m, source.weights)
    p, n, r = a.points, a.target[:, 3:6], a.weighted
    weight = _huber_weight(r, a.inliers, s.huber_m)
    # rows [d r / d (rho, phi) | r] for a left perturbation; one product gives J^T W J and J^T W r
    jacobian = torch.cat([n, torch.linalg.cross(p, n)], dim=-1)  # [N, 6]
    if a.weight is not None:
        jacobian = jacobian * a.weight[:, None]
    rows = torch.cat([jacobian, r[:, None]], dim=-1)  # [N, 7]
    if values is not None:
        jac, rc, usable = _channel_rows(a, values, ref, ref.intrinsics)
        rows = torch.cat([rows, torch.cat([jac, rc[..., None]], dim=-1).reshape(-1, 7)])  # [N (1 + C), 7]
        weight = torch.cat([weight, _huber_weight(rc, usable, s.huber_m).reshape(-1)])
    return fusable_matmul((rows * weight[:, None]).T, rows).double()


def _solve(normal: Tensor, src_to_ref: Tensor, s: IcpSettings) -> Tensor:  # [7, 7] float64 -> the updated pose [4, 4]
    """The damped Gauss-Newton update of ``src_to_ref`` from ``[J^T W J | J^T W r]``."""
    hessian, gradient = normal[:6, :6], normal[:6, 6]
    eye = torch.eye(6, dtype=torch.float64, device=hessian.device)
    hessian = hessian + (s.damping * hessian.diagonal().mean() + 1e-12) * eye
    xi = -torch.linalg.solve_ex(hessian, gradient)[0]  # solve_ex: no error check, so no wait for the GPU
    return fusable_matmul(se3_exp(xi), src_to_ref)


def torch_step(
    src_to_ref: Tensor,  # [4, 4] float64
    points: Tensor,  # [N, 3] float32 source points, z = 0 where invalid
    values: Tensor | None,  # [N, C] float32 source channels
    weights: Tensor | None,  # [N] float32 depth-noise weights of the source points
    ref: IcpLevel,
    s: IcpSettings,
) -> Tensor:  # [4, 4] float64
    """One damped Gauss-Newton update against ``ref``: :class:`IcpSteps` is this, ``steps`` times."""
    return _gauss_newton_step(src_to_ref, _LevelSource(points, values, weights), ref, s)


def torch_joint_step(
    src_to_ref: Tensor,  # [4, 4] float64
    points: Tensor,  # [N, 3] float32 source points, z = 0 where invalid
    values: Tensor | None,  # [N, C] float32 source channels
    weights: Tensor | None,  # [N] float32 depth-noise weights of the source points
    ref: IcpLevel,
    s: IcpSettings,
    observations: Observations,
) -> Tensor:  # [4, 4] float64
    """:class:`IcpJoint` in PyTorch: one damped step of the dense terms and the observations together."""
    source = _LevelSource(points, values, weights)
    normal = _normal_matrix(src_to_ref, source, ref, s) + _observation_normal(src_to_ref, observations, ref.intrinsics)
    return _solve(normal, src_to_ref, s)


def torch_terms(
    src_to_ref: Tensor,  # [4, 4] float64
    points: Tensor,  # [N, 3] float32 source points, z = 0 where invalid
    values: Tensor | None,  # [N, C] float32 source channels
    packed: Tensor,  # [H * W, 7 (+ 3C + 1)] the reference level's rows
    intrinsics: Intrinsics,  # the reference level's camera
    max_distance_m: float,
    huber_m: float,
    weights: Tensor | None,  # [N] float32 depth-noise weights of the source points
) -> Tensor:  # [53] float64: normal matrix [49], truncated cost, correspondences, their sum r^2, source points
    """:class:`IcpTerms` in PyTorch (the cost's cap and the association as the steps have them)."""
    num_channels = (packed.shape[1] - 8) // 3 if packed.shape[1] > 7 else 0
    ref = IcpLevel(intrinsics, packed, num_channels)
    s = IcpSettings(max_distance_m=max_distance_m, huber_m=huber_m)
    source = _LevelSource(points, values, weights)
    a = _associate(src_to_ref, points, ref, max_distance_m, weights)
    valid = points[:, 2] > 0
    cost = _truncated_cost(a.weighted, a.inliers, valid, s)
    if values is not None:
        cost = cost + _channel_cost(a, values, ref, s)
    stats = torch.stack(
        [cost, a.inliers.sum().double(), (a.residual.double().square() * a.inliers).sum(), valid.sum().double()]
    )
    return torch.cat([_normal_matrix(src_to_ref, source, ref, s, a).reshape(-1), stats])


def _truncated_cost(r: Tensor, inliers: Tensor, valid: Tensor, s: IcpSettings) -> Tensor:  # [] float64
    """Sum over valid source points of min(r^2, (3 huber_m)^2), points without a match counting the cap.

    Comparable between poses, unlike the inlier RMS: a pose that loses hard points does not gain.
    """
    cap = (3 * s.huber_m) ** 2
    return torch.where(inliers, r.double().square().clamp(max=cap), cap * valid.double()).sum()


def _channel_cost(a: _Association, values: Tensor, ref: IcpLevel, s: IcpSettings) -> Tensor:  # []
    """The channels' share of the truncated cost at an association (every usable source channel value)."""
    _, rc, usable = _channel_rows(a, values, ref, ref.intrinsics)
    cap = (3 * s.huber_m) ** 2
    return torch.where(usable, rc.double().square().clamp(max=cap), 0.0).sum()


@dataclass(frozen=True)
class DeviceAlignment:
    """:func:`align_device`'s result, still on the device (nothing read back)."""

    src_to_ref: Tensor  # [4, 4] float64
    inliers: Tensor  # [] float64, source points with a correspondence at the result
    sum_sq_m2: Tensor  # [] float64, their summed squared point-to-plane residual (m^2)
    valid_source: Tensor  # [] float64, source points with depth


def align_device(
    depth: Tensor,  # [H, W] m, 0 = invalid: the source (new) frame
    intrinsics: Intrinsics,
    reference: list[IcpLevel],  # icp_pyramid of the reference frame, same intrinsics and level count
    init_src_to_ref: Tensor,  # [4, 4] float64
    s: IcpSettings,
    channels: Sequence[Tensor | None] | None = None,  # source_channels per level, where its reference has channels
    kernels: IcpKernels | None = None,  # compiled parts (``Kernels.icp``); None = this module's PyTorch code
) -> DeviceAlignment:
    """:func:`align_depth` without reading the result back (fixed shapes throughout, no host wait).

    The result is :func:`refine_device`'s, or the start where the start's full-resolution
    truncated cost is lower.
    """
    kernels = kernels or IcpKernels()
    init = init_src_to_ref.to(device=depth.device, dtype=torch.float64)
    pose, finest = _refine(depth, intrinsics, reference, init, s, channels, kernels)
    if kernels.terms is None:
        return _keep_better(init, pose, finest, reference[-1], s)
    start, end = (_terms(kernels.terms, p, finest, reference[-1], s)[49:] for p in (init, pose))
    worse = end[0] > start[0]
    stats = torch.where(worse, start, end)
    return DeviceAlignment(torch.where(worse, init, pose), stats[1], stats[2], stats[3])


def refine_device(
    depth: Tensor,  # [H, W] m, 0 = invalid: the source (new) frame
    intrinsics: Intrinsics,
    reference: list[IcpLevel],  # icp_pyramid of the reference frame, same intrinsics and level count
    init_src_to_ref: Tensor,  # [4, 4] float64
    s: IcpSettings,
    channels: Sequence[Tensor | None] | None = None,  # source_channels per level, where its reference has channels
    kernels: IcpKernels | None = None,  # compiled parts (``Kernels.icp``); None = this module's PyTorch code
    observations: Observations | None = None,  # sparse points joining the finest level's steps
) -> Tensor:  # [4, 4] float64 source camera frame -> reference camera frame
    """The pose after every level's Gauss-Newton steps, with no check against the start.

    For callers that judge the result themselves: :func:`align_device` costs two more
    full-resolution passes to compare it with the start. ``observations`` join the finest level
    (one joint step after its own); the points then hold the pose where the start was right.
    """
    init = init_src_to_ref.to(device=depth.device, dtype=torch.float64)
    return _refine(depth, intrinsics, reference, init, s, channels, kernels or IcpKernels(), observations)[0]


def _refine(
    depth: Tensor,
    intrinsics: Intrinsics,
    reference: list[IcpLevel],
    pose: Tensor,  # [4, 4] float64 on the device
    s: IcpSettings,
    channels: Sequence[Tensor | None] | None,
    kernels: IcpKernels,
    observations: Observations | None = None,
) -> tuple[Tensor, _LevelSource]:  # the pose [4, 4] float64, the finest level's source
    iterations = s.steps_for(intrinsics.width)
    if len(reference) != len(iterations):
        raise ShapeError(f"reference pyramid has {len(reference)} levels, settings ask for {len(iterations)}")
    if channels is not None and len(channels) != len(iterations):
        raise ShapeError(f"source channels have {len(channels)} levels, settings ask for {len(iterations)}")
    points = _source_points(vertex_map(depth, intrinsics), len(iterations))
    weights = _noise_weights(points, s.depth_noise)
    levels = zip(_level_intrinsics(intrinsics, len(iterations)), points, reference, iterations, strict=True)
    for i, (k, src, ref, steps) in enumerate(levels):
        if k.shape != ref.intrinsics.shape:
            raise ShapeError(f"source level is {k.shape}, reference level {ref.intrinsics.shape}")
        source = _LevelSource(src, None if channels is None else channels[i], weights[i])
        if kernels.steps is not None:
            pose = kernels.steps(pose, *source, ref, s, steps)
        else:
            for _ in range(steps):
                pose = _gauss_newton_step(pose, source, ref, s)
    if observations is not None and iterations[-1] > 0:  # one joint step from the dense optimum
        if kernels.joint is not None:
            pose = kernels.joint(pose, *source, reference[-1], s, observations)
        else:
            normal = _dense_normal(pose, source, reference[-1], s, kernels) + _observation_normal(pose, observations, k)
            pose = _solve(normal, pose, s)
    return pose, source


def _dense_normal(
    pose: Tensor, source: _LevelSource, ref: IcpLevel, s: IcpSettings, kernels: IcpKernels
) -> Tensor:  # [7, 7] float64
    """The dense terms' ``[J^T W J | J^T W r]`` at ``pose``, compiled where the kernels have it."""
    if kernels.terms is None:
        return _normal_matrix(pose, source, ref, s)
    return _terms(kernels.terms, pose, source, ref, s)[:49].reshape(7, 7)


def _noise_weights(points: list[Tensor], noise: DepthNoise | None) -> list[Tensor | None]:  # per level [N]
    """Each level's depth-noise weights (each relative to its own median depth), or None per level."""
    return [None if noise is None else noise.weights(p[:, 2]) for p in points]


def _terms(
    terms: IcpTerms, pose: Tensor, source: _LevelSource, ref: IcpLevel, s: IcpSettings
) -> Tensor:  # pose [4, 4] float64 -> [53] float64
    points, values, weights = source
    return terms(pose, points, values, ref.packed, ref.intrinsics, s.max_distance_m, s.huber_m, weights)


def _keep_better(
    init: Tensor,  # [4, 4] float64
    pose: Tensor,  # [4, 4] float64
    source: _LevelSource,  # the finest level's
    ref: IcpLevel,
    s: IcpSettings,
) -> DeviceAlignment:
    """``pose``, or ``init`` where its full-resolution truncated cost is lower.

    On a view with a weakly constrained direction the coarsest level's association can move a right
    start centimetres away, and the finer levels do not bring it back.
    """
    points, values, weights = source
    valid_source = points[:, 2] > 0
    a0, a = (_associate(p, points, ref, s.max_distance_m, weights) for p in (init, pose))  # one association each
    r0, inliers0, r, inliers = a0.residual, a0.inliers, a.residual, a.inliers
    cost0 = _truncated_cost(a0.weighted, inliers0, valid_source, s)
    cost = _truncated_cost(a.weighted, inliers, valid_source, s)
    if values is not None:
        cost0 = cost0 + _channel_cost(a0, values, ref, s)
        cost = cost + _channel_cost(a, values, ref, s)
    worse = cost > cost0
    pose, r, inliers = torch.where(worse, init, pose), torch.where(worse, r0, r), torch.where(worse, inliers0, inliers)
    return DeviceAlignment(
        pose, inliers.sum().double(), (r.double().square() * inliers).sum(), valid_source.sum().double()
    )


def align_depth(
    depth: Tensor,  # [H, W] m, 0 = invalid: the source (new) frame
    intrinsics: Intrinsics,
    reference: list[IcpLevel],  # icp_pyramid of the reference frame, same intrinsics and level count
    init_src_to_ref: Tensor,  # [4, 4] float64
    s: IcpSettings,
    kernels: IcpKernels | None = None,  # compiled parts (``Kernels.icp``); None = this module's PyTorch code
) -> IcpResult:
    """Refine ``init_src_to_ref`` so the source depth lies on the reference surface (one host read)."""
    result = align_device(depth, intrinsics, reference, init_src_to_ref, s, kernels=kernels)
    stats = torch.stack([result.inliers, result.sum_sq_m2, result.valid_source])
    host = torch.cat([result.src_to_ref.reshape(-1), stats]).cpu()  # the pose and its statistics in one read
    count_f, sq_f, total_f = host[16:].tolist()
    rms = (sq_f / count_f) ** 0.5 if count_f > 0 else float("inf")
    return IcpResult(host[:16].reshape(4, 4), count_f / total_f if total_f > 0 else 0.0, rms)
