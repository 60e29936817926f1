"""The SLAM loop's sections of :class:`~sgs_slam_core.config.SlamConfig` (rendering and semantics have their own).

Defaults are SGS-SLAM's Replica values (paper supplementary and released config); presets override.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

from sgs_slam_core.errors import ConfigError, ShapeError
from sgs_slam_core.geometry.depth_noise import DepthNoise
from sgs_slam_core.geometry.gravity import OPTICAL_IN_BODY, pose_from_xyz_rpy
from sgs_slam_core.geometry.icp import IcpSettings

__all__ = [
    "AdamTrackerSettings",
    "DensifySettings",
    "FeatureSettings",
    "GaussNewtonSettings",
    "GuardSettings",
    "KeyframeSettings",
    "LiveSettings",
    "MapAlignmentName",
    "MapFrameSettings",
    "MappingSettings",
    "MotionSettings",
    "TrackerName",
    "TrackingSettings",
]

TrackerName = Literal["adam", "gauss_newton"]
MapAlignmentName = Literal["optical", "mount", "floor"]  # the values of geometry.gravity.MapAlignment


def _positive(section: str, **values: float) -> None:
    for name, value in values.items():
        if not value > 0:
            raise ConfigError(f"{section}.{name} must be > 0, got {value}")


def _check_view_test(prefix: str, radius_m: float | None, angle_deg: float, min_age: int) -> None:
    """The "a keyframe took this view long ago" test's settings: ``{prefix}_radius_m`` and the rest."""
    if radius_m is not None and not radius_m > 0:
        raise ConfigError(f"{prefix}_radius_m must be > 0 or null, got {radius_m}")
    if not 0 < angle_deg <= 180:
        raise ConfigError(f"{prefix}_angle_deg must be in (0, 180], got {angle_deg}")
    if min_age < 1:
        raise ConfigError(f"{prefix}_min_age must be >= 1, got {min_age}")


def _non_negative(section: str, **values: float) -> None:
    for name, value in values.items():
        if value < 0:
            raise ConfigError(f"{section}.{name} must be >= 0, got {value}")


@dataclass(frozen=True)
class GaussNewtonSettings:
    """The Gauss-Newton tracker: the map rendered at the prediction, the frame aligned to it.

    Point-to-plane residuals of the frame's points against the rendered depth, and the frame's
    intensity (and semantic features) against the rendered colour (and semantics) through their
    image gradients, coarse to fine, Huber-weighted, Levenberg-damped.

    Attributes:
        iterations: Gauss-Newton steps per pyramid level, coarsest first (the last is the full image;
            levels narrower than 40 px are left out, ``geometry.icp.IcpSettings.min_width``).
        max_distance_m: correspondences farther apart than this (m) are left out.
        huber_m: residuals beyond this (m, or its equivalent for the channels) are down-weighted.
        color_scale_m: a colour difference of 1 (the full range) weighs as this many metres of
            point-to-plane residual (of the frame's intensity, BT.601 luma); 0 = depth only.
        semantic_scale_m: the same for a semantic feature difference of 1; 0 = no semantic term.
        keep_start: keep the starting pose where its tracking loss is lower than the solve's (the
            Adam tracker keeps its best evaluated pose, the start included), and the alignment
            skips its own check against the start. Off, the solve wins wherever the alignment's
            own cost is lower than at the start.
        feature_weight: the frame's feature matches (the inliers of its feature pose against the
            last accepted frame) join the finest level's steps as reprojection terms, a pixel of
            error counting as the metres it spans at the point's depth and each match as this many
            pixels of a 160x120 frame's dense terms (scaled by the frame's pixel count, so the
            matches keep their share at any size); they hold the pose where the geometry leaves a
            direction free (a camera over a desk slides along it). 0 = not used.
        depth_noise: the depth camera's axial noise, ``base_m + quadratic_per_m (z - offset_m)^2``
            (m; a Kinect v1's by default): each point-to-plane residual is weighed by the noise at
            the frame's median depth over the noise at the point's depth, so ``huber_m`` is metres
            at the median depth and the far background's noise does not outvote the near
            surfaces. Null: every point weighs the same.
    """

    iterations: tuple[int, ...] = (6, 4, 3)
    max_distance_m: float = 0.1
    huber_m: float = 0.01
    color_scale_m: float = 1.0
    semantic_scale_m: float = 0.0
    keep_start: bool = False
    feature_weight: float = 10.0
    depth_noise: DepthNoise | None = field(default_factory=DepthNoise)

    def __post_init__(self) -> None:
        if not self.iterations or any(n < 0 for n in self.iterations) or len(self.iterations) > 6:
            raise ConfigError(
                f"tracking.gauss_newton.iterations must be 1 to 6 counts >= 0, got {list(self.iterations)}"
            )
        _positive("tracking.gauss_newton", max_distance_m=self.max_distance_m, huber_m=self.huber_m)
        _non_negative(
            "tracking.gauss_newton",
            color_scale_m=self.color_scale_m,
            semantic_scale_m=self.semantic_scale_m,
            feature_weight=self.feature_weight,
        )

    @property
    def icp(self) -> IcpSettings:
        """The alignment's settings (damping and the narrowest level: ``IcpSettings``' defaults)."""
        return IcpSettings(self.iterations, self.max_distance_m, self.huber_m, depth_noise=self.depth_noise)


@dataclass(frozen=True)
class AdamTrackerSettings:
    """The paper's tracker (``tracking.method: adam``): Adam steps on the rendering loss.

    Attributes:
        iterations: budget of optimiser steps per frame.
        lr_rotation, lr_translation: Adam learning rates of the camera-frame rotation (rad) and
            translation (m) increment; the paper's quaternion rates map to twice their value here.
        early_stop: stop before the budget once the best loss stops improving: 5 steps in a row
            fail to lower it by more than 0.1 % (``slam.tracker``'s constants).
    """

    iterations: int = 40
    lr_rotation: float = 8e-4
    lr_translation: float = 2e-3
    early_stop: bool = True

    def __post_init__(self) -> None:
        _positive(
            "tracking.adam",
            iterations=self.iterations,
            lr_rotation=self.lr_rotation,
            lr_translation=self.lr_translation,
        )


@dataclass(frozen=True)
class TrackingSettings:
    """Camera tracking against the fixed map: the tracker, and the loss that judges every tracker's pose.

    Attributes:
        method: ``adam`` (the paper's: Adam steps on the rendering loss, each rendering the map and
            back-propagating through the renderer; ``adam`` section) or ``gauss_newton``
            (``gauss_newton`` section).
        sil_threshold: only pixels with rendered silhouette above this (and valid depth) count.
        weight_depth, weight_color, weight_semantic: weights of the L1 sums.
        use_gt_pose: replace tracking by the ground-truth pose (ablation; needs ground truth).
        adam: the Adam tracker's settings.
        gauss_newton: the Gauss-Newton tracker's settings.
    """

    method: TrackerName = "adam"
    sil_threshold: float = 0.99
    weight_depth: float = 1.0
    weight_color: float = 0.5
    weight_semantic: float = 0.05
    use_gt_pose: bool = False
    adam: AdamTrackerSettings = field(default_factory=AdamTrackerSettings)
    gauss_newton: GaussNewtonSettings = field(default_factory=GaussNewtonSettings)

    def __post_init__(self) -> None:
        _non_negative(
            "tracking",
            weight_depth=self.weight_depth,
            weight_color=self.weight_color,
            weight_semantic=self.weight_semantic,
        )
        if not 0 <= self.sil_threshold < 1:
            raise ConfigError(f"tracking.sil_threshold must be in [0, 1), got {self.sil_threshold}")


@dataclass(frozen=True)
class MotionSettings:
    """Where tracking starts: the motion prediction and the depth ICP that refines it.

    Attributes:
        constant_velocity: predict from the last two poses (else start at the last pose).
        icp_iterations: Gauss-Newton steps of a depth-to-depth ICP against the last tracked frame
            that refines the motion prediction before tracking, per pyramid level, coarsest first
            (the last level is the full image); empty = no ICP. Its correspondences reach 0.1 m and
            its result needs 30 % of the frame's pixels with depth to find one
            (``geometry.icp.IcpSettings``, ``slam.motion.ICP_MIN_INLIERS``).
        icp_min_gap: run the ICP only on frames that come at least this many camera frame
            intervals (the shortest gap between two tracked frames) after the last tracked one,
            i.e. when frames were dropped and the prediction extrapolates; 0 = on every frame
            (less accurate on Kinect depth, where the photometric terms do better alone).
        icp_reference_distance_m, icp_reference_angle_deg: the ICP's reference frame stays until a
            tracked frame's camera centre is this far (m) from the reference's, or its optical axis
            turned this much (degrees), or the ICP against it failed; then that frame becomes the
            reference.
            Odometry against a reference kept over several frames drifts per reference instead of
            per frame. Either 0: every tracked frame is the next one's reference.
    """

    constant_velocity: bool = True
    icp_iterations: tuple[int, ...] = (6, 4, 3)
    icp_min_gap: float = 1.5
    icp_reference_distance_m: float = 0.0
    icp_reference_angle_deg: float = 0.0

    def __post_init__(self) -> None:
        if any(n < 0 for n in self.icp_iterations) or len(self.icp_iterations) > 6:
            raise ConfigError(f"motion.icp_iterations must be at most 6 counts >= 0, got {list(self.icp_iterations)}")
        _non_negative(
            "motion",
            icp_min_gap=self.icp_min_gap,
            icp_reference_distance_m=self.icp_reference_distance_m,
        )
        if not 0 <= self.icp_reference_angle_deg <= 90:
            raise ConfigError(f"motion.icp_reference_angle_deg must be in [0, 90], got {self.icp_reference_angle_deg}")

    @property
    def icp(self) -> IcpSettings | None:
        """The ICP that refines the motion prediction, or None when off."""
        if not any(self.icp_iterations):
            return None
        return IcpSettings(iterations=self.icp_iterations)


@dataclass(frozen=True)
class FeatureSettings:
    """Sparse ORB features of each tracked frame: what the frames say about the motion, apart from the map.

    The motion model starts tracking from the pose the features give against the last accepted
    frame (RANSAC PnP on its depth) where the constant-velocity guess disagrees with it; the guard
    rejects a tracked pose the features contradict; a lost camera is found again by matching its
    features against the keyframes'.

    Attributes:
        enabled: extract and use features (off: constant velocity and the depth ICP only, no
            relocalization).
        count: ORB keypoints per frame at most.
        fast_threshold: FAST corner threshold (intensity levels of 255): lower finds corners in
            blurred frames.
        min_inliers: a feature pose needs at least this many matches within ``reprojection_px``.
        reprojection_px: RANSAC's inlier threshold (px).
    """

    enabled: bool = True
    count: int = 300
    fast_threshold: int = 10
    min_inliers: int = 20
    reprojection_px: float = 2.0

    def __post_init__(self) -> None:
        _positive(
            "features",
            count=self.count,
            fast_threshold=self.fast_threshold,
            reprojection_px=self.reprojection_px,
        )
        if self.min_inliers < 6:
            raise ConfigError(f"features.min_inliers must be >= 6 (a PnP needs them), got {self.min_inliers}")


@dataclass(frozen=True)
class MapFrameSettings:
    """How the map frame is oriented: chosen on the first frame of an empty map.

    Attributes:
        alignment: ``optical`` (the first camera's optical frame: x right, y down, z forward),
            ``mount`` (z up: the first pose of the body the camera is mounted on) or ``floor``
            (z up, levelled on the first frame's floor plane, origin on the floor; ``mount`` when
            no floor is seen).
        camera_mount: pose of the camera optical frame in the body frame: x y z (m) roll pitch yaw
            (rad), or x y z qx qy qz qw; the default is a level, forward-looking camera.
        floor_max_tilt_deg: the floor's normal may differ this much from the mount's up (deg).
    """

    alignment: MapAlignmentName = "optical"
    camera_mount: tuple[float, ...] = OPTICAL_IN_BODY
    floor_max_tilt_deg: float = 30.0

    def __post_init__(self) -> None:
        try:
            pose_from_xyz_rpy(self.camera_mount)
        except ShapeError as err:
            raise ConfigError(f"map_frame.camera_mount: {err}") from err
        if not 1.0 <= self.floor_max_tilt_deg <= 89.0:
            raise ConfigError(f"map_frame.floor_max_tilt_deg must be in [1, 89], got {self.floor_max_tilt_deg}")


@dataclass(frozen=True)
class MappingSettings:
    """Map optimisation over a window of keyframes.

    Attributes:
        iterations: optimiser steps per mapped frame; each renders one random window frame.
        current_frame_steps: the first this many steps render the newest frame (the one just
            tracked, whose new Gaussians the next frame is tracked against), the rest a random window
            frame; 0 = every step random, as the reference. Matters when a frame gets few steps
            (live on a slow machine).
        every: map every n-th frame (1 = every frame, as the reference).
        lr_*: Adam learning rates per Gaussian field (eps 1e-15, as the reference).
        weight_depth, weight_color, weight_semantic: loss weights.
        ssim_weight: colour and semantic terms are (1 - w) L1 + w (1 - SSIM).
        prune_iterations: iterations after whose step transparent / huge Gaussians are removed (the
            optimiser state is sliced, so no step is lost, unlike the reference).
        prune_opacity: remove Gaussians below this opacity.
        prune_scale_ratio: remove Gaussians larger than this times the scene radius.
        scene_radius_depth_ratio: scene radius = max first-frame depth / this.
        max_scale_px: after each step, Gaussians the step's camera sees are shrunk to at
            most this many pixels of standard deviation at their depth there (None = unbounded, as
            the reference): over thousands of steps on revisited views the splats otherwise keep
            growing, and every render with them. Off by default because on coarse images a bound
            also narrows splats the map needs (1.5 px loses accuracy at 160x120).
        refresh_labels: after mapping, set every Gaussian's class id from its semantic features
            (``semantic.fusion: votes``: reset the features of Gaussians the votes give another class).
        refresh_labels_keyframes_only: only after mapping a frame that becomes a keyframe (on by
            default in live runs, ``live.overlay``). The Gaussians a frame adds take their class from
            its labels either way; older ones follow within ``keyframes.every`` frames.
    """

    iterations: int = 60
    current_frame_steps: int = 0
    every: int = 1
    lr_means: float = 1e-4
    lr_colors: float = 2.5e-3
    lr_semantics: float = 2.5e-3
    lr_opacities: float = 5e-2
    lr_scales: float = 1e-3
    lr_quats: float = 1e-3
    weight_depth: float = 1.0
    weight_color: float = 0.5
    weight_semantic: float = 0.1
    ssim_weight: float = 0.2
    prune_iterations: tuple[int, ...] = (0, 20)
    prune_opacity: float = 0.005
    prune_scale_ratio: float = 0.1
    scene_radius_depth_ratio: float = 3.0
    max_scale_px: float | None = None
    refresh_labels: bool = True
    refresh_labels_keyframes_only: bool = False

    def __post_init__(self) -> None:
        _non_negative(
            "mapping",
            iterations=self.iterations,
            current_frame_steps=self.current_frame_steps,
            weight_depth=self.weight_depth,
            weight_color=self.weight_color,
            weight_semantic=self.weight_semantic,
        )
        _positive(
            "mapping",
            every=self.every,
            lr_means=self.lr_means,
            lr_colors=self.lr_colors,
            lr_semantics=self.lr_semantics,
            lr_opacities=self.lr_opacities,
            lr_scales=self.lr_scales,
            lr_quats=self.lr_quats,
            scene_radius_depth_ratio=self.scene_radius_depth_ratio,
            prune_scale_ratio=self.prune_scale_ratio,
        )
        if not 0 <= self.ssim_weight <= 1:
            raise ConfigError(f"mapping.ssim_weight must be in [0, 1], got {self.ssim_weight}")
        if self.max_scale_px is not None and not self.max_scale_px > 0:
            raise ConfigError(f"mapping.max_scale_px must be > 0 px or null, got {self.max_scale_px}")


@dataclass(frozen=True)
class DensifySettings:
    """Adding Gaussians for unexplained pixels (after tracking, before mapping).

    Attributes:
        sil_threshold: pixels whose rendered silhouette is below this get new Gaussians.
        depth_error_factor: also where the depth says new geometry is in front: rendered depth
            greater than measured and the error above this times the median error (zeros included,
            as the reference).
        resolution_scale: add (and initialise) Gaussians from a copy of the frame scaled by this
            (SplaTAM-S uses 0.5); radii grow accordingly.
        max_width: Gaussian budget: add them from a copy of the frame at most this wide (px; it
            scales further where ``resolution_scale`` does not), so a map's density stops growing
            with the camera's resolution (None = the frame's own width).
        initial_opacity: opacity of new Gaussians.
        max_new_per_frame: cap on Gaussians added per frame (random subset; None = no cap).
        min_spacing: Gaussian budget: a pixel adds no Gaussian when the map already holds one within
            its cell, ``min_spacing`` times the pixel's footprint (rounded up to a power of two);
            revisits then add only where the map has nothing (None = off, one per unexplained pixel).
        max_gaussians: hard cap on the map: before new Gaussians join, the least opaque leave so
            that the count stays at most this (None = no cap; classes locked by edits never leave).
        front_window: pixels flagged by the depth test count as a mapped edge, not new geometry,
            where some pixel within this window (odd, px) renders a depth not that far behind the
            measurement: an edge renders a blend of foreground and background, deeper than the
            measured foreground (1 = the reference's per-pixel test alone: no edges; with it every
            revisit of a mapped edge adds Gaussians, and a long run's map grows without end).
        revisit_radius_m: a frame revisits when a keyframe at least ``revisit_min_age`` frames
            older was taken within this distance (m) and ``revisit_angle_deg`` of its optical axis;
            there a mapped edge's pixels add no Gaussians (None = no frame revisits: edges always
            add, as with the reference's test). Chosen so that no frame of TUM fr3/teddy or the
            room's orbit revisits, while a looping camera does.
        revisit_angle_deg: see ``revisit_radius_m``.
        revisit_min_age: see ``revisit_radius_m`` (frames): the last keyframes always lie near.
    """

    sil_threshold: float = 0.5
    depth_error_factor: float = 50.0
    resolution_scale: float = 1.0
    max_width: int | None = None
    initial_opacity: float = 0.5
    max_new_per_frame: int | None = None
    min_spacing: float | None = None
    max_gaussians: int | None = None
    front_window: int = 3
    revisit_radius_m: float | None = 0.2
    revisit_angle_deg: float = 10.0
    revisit_min_age: int = 30

    def __post_init__(self) -> None:
        if not 0 < self.resolution_scale <= 1:
            raise ConfigError(f"densify.resolution_scale must be in (0, 1], got {self.resolution_scale}")
        if not 0 < self.initial_opacity < 1:
            raise ConfigError(f"densify.initial_opacity must be in (0, 1), got {self.initial_opacity}")
        _positive("densify", depth_error_factor=self.depth_error_factor)
        if self.max_new_per_frame is not None and self.max_new_per_frame < 1:
            raise ConfigError("densify.max_new_per_frame must be >= 1 or null")
        if self.min_spacing is not None and not self.min_spacing > 0:
            raise ConfigError(f"densify.min_spacing must be > 0 or null, got {self.min_spacing}")
        if self.max_gaussians is not None and self.max_gaussians < 1:
            raise ConfigError(f"densify.max_gaussians must be >= 1 or null, got {self.max_gaussians}")
        _check_view_test("densify.revisit", self.revisit_radius_m, self.revisit_angle_deg, self.revisit_min_age)
        if self.front_window < 1 or self.front_window % 2 == 0:
            raise ConfigError(f"densify.front_window must be odd and >= 1, got {self.front_window}")
        if self.max_width is not None and self.max_width < 8:
            raise ConfigError(f"densify.max_width must be >= 8 px or null, got {self.max_width}")

    def scale_for(self, width: int) -> float:
        """The scale of the frame copy Gaussians are added from, for frames ``width`` px wide (<= 1)."""
        if self.max_width is None:
            return self.resolution_scale
        return min(self.resolution_scale, self.max_width / width)


@dataclass(frozen=True)
class KeyframeSettings:
    """Keyframe storage, selection and weighting (each of the paper's three steps switchable).

    Attributes:
        every: frame t becomes a keyframe when (t + 1) % every == 0 (and frame 0), as the reference.
        window_size: frames per mapping window, current frame and last keyframe included (<= 25 in the paper).
        geometric_filter: keep only keyframes whose overlap (the share of 1600 of the frame's pixels
            that project into the keyframe's view) exceeds ``geometric_threshold`` (paper eta; off =
            keep every keyframe with any overlap, as the released code).
        geometric_threshold: eta (0.05 in the paper).
        semantic_filter: drop candidates whose label mIoU with the current frame exceeds
            ``semantic_threshold``: near-identical views add little (paper; not in the code).
        semantic_threshold: that mIoU (the paper's T_sem, 0.7).
        uncertainty_weighting: weight each window frame's mapping loss by U(t) = exp(-tau (t - t0)),
            t0 the oldest frame of the window (paper; not in the code).
        uncertainty_tau: tau per frame.
        max_keyframes: keyframes held with their images (None = no cap); past it the view a newer
            keyframe covers best leaves (``slam.keyframe_store``), so revisits do not add memory.
        max_megabytes: cap on the host memory of the keyframes' images (MiB; None = no cap).
        keep_recent: the newest this many keyframes are never evicted (the window's freshest views).
        replace_radius_m: a new keyframe takes the place of a held one at least ``replace_min_age``
            frames older whose camera centre lies within this distance (m) and ``replace_angle_deg``
            of its optical axis, at once rather than when the store is full: a revisited place keeps
            one view, so the store stops growing from the first revisit (None = only the caps evict).
            The defaults are ``densify.revisit_*``'s: the same test of a revisit.
        replace_angle_deg: see ``replace_radius_m``.
        replace_min_age: see ``replace_radius_m`` (frames): the last keyframes always lie near.
    """

    every: int = 5
    window_size: int = 24
    geometric_filter: bool = True
    geometric_threshold: float = 0.05
    semantic_filter: bool = True
    semantic_threshold: float = 0.7
    uncertainty_weighting: bool = True
    uncertainty_tau: float = 0.002
    max_keyframes: int | None = 64
    max_megabytes: float | None = 512.0
    keep_recent: int = 4
    replace_radius_m: float | None = 0.2
    replace_angle_deg: float = 10.0
    replace_min_age: int = 30

    def __post_init__(self) -> None:
        _positive("keyframes", every=self.every)
        _non_negative("keyframes", keep_recent=self.keep_recent)
        _check_view_test("keyframes.replace", self.replace_radius_m, self.replace_angle_deg, self.replace_min_age)
        if self.max_keyframes is not None and self.max_keyframes < max(self.keep_recent, 2):
            raise ConfigError(f"keyframes.max_keyframes must be >= max(keep_recent, 2) or null: {self.max_keyframes}")
        if self.max_megabytes is not None and not self.max_megabytes > 0:
            raise ConfigError(f"keyframes.max_megabytes must be > 0 or null, got {self.max_megabytes}")
        if self.window_size < 2:
            raise ConfigError(f"keyframes.window_size must be >= 2, got {self.window_size}")
        if not (0 <= self.geometric_threshold < 1 and 0 < self.semantic_threshold <= 1):
            raise ConfigError("keyframes thresholds must be fractions")
        _non_negative("keyframes", uncertainty_tau=self.uncertainty_tau)


@dataclass(frozen=True)
class GuardSettings:
    """Tracking-failure detection: a flagged frame is not mapped, so the map stays intact.

    Attributes:
        enabled: switch the guard on (it also flags a frame whose pixels are less than 5 % both
            measured and well mapped).
        warmup_frames: frames tracked before the guard starts judging.
        residual_jump: flag when the mean depth residual exceeds this times the median of the last 20
            accepted frames (and 2 cm, the noise floor: ``slam.guard``'s constants).
        loss_jump: flag when the per-pixel tracking loss exceeds this times the recent median.
        retry: a flagged frame is tracked once more, from its feature pose where the features give
            one and it was not the start already, else from the last accepted pose (without the
            motion prediction, refined by the motion ICP when that is on), and accepted if that
            passes; a camera that reversed, or came back after a loss, is found again. A frame
            that still fails takes its feature pose (with ``relocalize_min_inliers`` matches),
            accepted and mapped if that pose passes, else kept unmapped: the camera is not lost.
        min_feature_agreement: flag a pose that explains fewer than this share of the feature
            matches the frame's feature pose (against the last accepted frame) explains, each
            within ``features.reprojection_px`` (0 = no feature check). Against a feature pose with
            ``relocalize_min_inliers`` matches, a pose turned over 5 deg from it is flagged too, and
            one that explains 90 % of its matches is not flagged for a residual or loss jump
            (``slam.guard``'s constants).
        lost_after: this many flagged frames in a row mean the camera is lost: nothing is mapped
            and every frame is relocalized until one is found again (0 = never lost).
        max_feature_frames: at most this many frames in a row take their features' pose when the
            tracker's fails (0 = no limit); the next such frame counts towards ``lost_after``: each
            feature pose chains on the last accepted frame, and a chain the map keeps disagreeing
            with has drifted from it.
        relocalize_min_inliers: a lost frame is tracked from at most 3 candidate poses (the keyframes
            whose features match it best, and the last accepted frame's, each solved by PnP first:
            ``slam.localization.RELOCALIZE_CANDIDATES``); a candidate needs this many feature matches
            agreeing with its PnP pose; the tracked pose from it must then pass every test above.
    """

    enabled: bool = True
    warmup_frames: int = 3
    residual_jump: float = 6.0
    loss_jump: float = 6.0
    retry: bool = True
    min_feature_agreement: float = 0.7
    lost_after: int = 2
    max_feature_frames: int = 20
    relocalize_min_inliers: int = 30

    def __post_init__(self) -> None:
        _positive("guard", residual_jump=self.residual_jump, loss_jump=self.loss_jump)
        counts = {"lost_after": self.lost_after, "max_feature_frames": self.max_feature_frames}
        _non_negative("guard", warmup_frames=self.warmup_frames, **counts)
        if not 0 <= self.min_feature_agreement <= 1:
            raise ConfigError(f"guard.min_feature_agreement must be in [0, 1], got {self.min_feature_agreement}")
        if self.relocalize_min_inliers < 6:
            raise ConfigError(f"guard.relocalize_min_inliers must be >= 6, got {self.relocalize_min_inliers}")


def _default_live_overlay() -> dict[str, Any]:
    return {
        "tracking": {"method": "gauss_newton"},
        "mapping": {"refresh_labels_keyframes_only": True},
        "semantic": {"fusion": "votes"},
    }


@dataclass(frozen=True)
class LiveSettings:
    """Live operation (``--realtime``, the ROS nodes); lockstep runs ignore it.

    Attributes:
        overlay: config keys live runs use in place of lockstep's, by section (any key of any
            section: ``--set live.overlay.mapping.weight_color=0.25``; layers merge into the
            default). By default live runs track with Gauss-Newton, which renders the map twice a
            frame where Adam renders it at every step, so it keeps up with a camera; and re-decode
            every Gaussian's class after mapping a keyframe only, since the re-decoding costs a
            mapping job about a step's time on a CPU; and make a Gaussian's class the majority of
            the labelled views (``semantic.fusion: votes``), since live labels are a segmenter's:
            few (a few a second), late, and flickering. Live, a frame gets a few mapping steps where
            lockstep makes ``mapping.iterations``: the ``tum`` preset weighs the colour term less
            (``mapping.weight_color`` 0.25), spending them on the depth the tracker aligns to, and
            adds Gaussians where the measured depth lies in front of the map by 20 (not 50) times
            the median error (``densify.depth_error_factor``), since a few steps cannot pull a
            mapped surface onto geometry that appeared in front of it. ``mapping.every: N``
            optimises the map on every n-th tracked frame only, leaving the tracker more of the
            machine (every frame is still densified).
        min_map_steps: on the CPU, where tracking and mapping take turns, the least mean mapping
            steps of a frame's job (over the last ten jobs that optimised): a job below it makes the
            steps it owes even while the next frame waits, which may then be dropped (0 = none:
            mapping only fills the time between frames). 0 by default: on fr1/desk, where tracking
            alone can fill the frame period and the map then goes without a step for hundreds of
            frames, floors of 0.1 to 1 cost frames and did not make the trajectory measurably
            better run for run (BENCHMARKS.md); a steady map at fewer frames takes 1 or 2.
        geometry_lr_scale: live runs multiply ``mapping.lr_means`` and ``mapping.lr_scales`` (after
            the overlay) by this (1 = lockstep's rates): centres and sizes that move further per step
            can still fit noisy depth in a few steps a frame (the ``tum`` preset takes 3).
        label_buffer_s: when label images come apart from their frames (a segmenter's stream,
            ``--label-rate-hz``), how long mapped views are kept for theirs (s of stamps; a view is
            about 100 kB at 160x120, 1.5 MB at 640x480). A label image that finds no view is counted
            as unmatched.
    """

    overlay: dict[str, Any] = field(default_factory=_default_live_overlay, hash=False)
    min_map_steps: float = 0.0
    geometry_lr_scale: float = 1.0
    label_buffer_s: float = 3.0

    def __post_init__(self) -> None:
        if not 0 <= self.label_buffer_s <= 60:
            raise ConfigError(f"live.label_buffer_s must be in [0, 60] s, got {self.label_buffer_s}")
        if not self.geometry_lr_scale > 0:
            raise ConfigError(f"live.geometry_lr_scale must be > 0, got {self.geometry_lr_scale}")
        if not 0 <= self.min_map_steps <= 100:
            raise ConfigError(f"live.min_map_steps must be in [0, 100], got {self.min_map_steps}")
        for name, values in self.overlay.items():
            if name == "live" or not isinstance(values, dict):
                raise ConfigError(f"live.overlay.{name}: the overlay holds config sections and their keys")
