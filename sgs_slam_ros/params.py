"""Node parameters: one declaration each, with a value, a description, a range or choices.

Every parameter is either read-only (fixed at start-up: ``ros2 param describe`` says so) or applied
live: :class:`NodeParams` keeps ``values`` current and calls the node's hooks after a successful
``set``. All core settings are reachable through ``preset``, ``config_file`` and ``overrides``
(``key=value`` strings, e.g. ``tracking.adam.iterations=30``), resolved exactly like ``sgs-slam run``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import torch
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException, ParameterException
from rclpy.node import Node
from rclpy.parameter import Parameter

from sgs_slam_core.config import SlamConfig, load_config
from sgs_slam_core.geometry.gravity import OPTICAL_IN_BODY, MapAlignment
from sgs_slam_ros.qos import INPUT_QOS_CHOICES

__all__ = [
    "COMMON",
    "EDIT",
    "MAPPING",
    "TRACKING",
    "NodeParams",
    "ParamSpec",
    "ParameterError",
    "declare",
    "slam_config",
    "use_threads",
]


class ParameterError(ValueError):
    """A parameter given at start-up is unusable (wrong type, out of range, not a choice)."""


@dataclass(frozen=True)
class ParamSpec:
    """One ROS parameter."""

    name: str
    default: Any
    description: str
    bounds: tuple[float, float] | None = None
    choices: tuple[str, ...] | None = None
    read_only: bool = False
    string_list: bool = False  # a list of strings, default empty (see _descriptor)
    zero_is: str | None = None  # what 0 means where the other values start at 1 (e.g. "auto")


COMMON = (
    ParamSpec("preset", "tum", "core config preset: replica, scannet, tum, synthetic, *_fast", read_only=True),
    ParamSpec("config_file", "", "YAML file applied after the preset ('' = none)", read_only=True),
    ParamSpec(
        "overrides",
        [],
        "core config overrides 'section.key=value' (a list, or one string)",
        read_only=True,
        string_list=True,
    ),
    ParamSpec("device", "auto", "compute device", choices=("auto", "cpu", "cuda"), read_only=True),
    ParamSpec(
        "threads",
        0,
        "torch CPU threads of this process (0 = torch's default, one a core); the tracking and mapping threads "
        "each use them, so on a small CPU 1 avoids running more threads than cores",
        bounds=(0, 256),
        read_only=True,
    ),
    ParamSpec("map_frame", "map", "frame id of poses, paths, clouds and the /tf root", read_only=True),
    ParamSpec("camera_frame", "", "frame id of the camera ('' = header.frame_id of rgb/image)", read_only=True),
    ParamSpec("input_qos", "best_effort", "image subscription QoS", choices=INPUT_QOS_CHOICES, read_only=True),
    ParamSpec(
        "sync_queue_size", 10, "colour and depth messages kept for synchronisation", bounds=(1, 1000), read_only=True
    ),
    ParamSpec(
        "input_queue_size",
        30,
        "messages each input subscription holds until the node takes them (DDS reader history depth; "
        "a deeper queue rides out a busy moment instead of losing frames)",
        bounds=(1, 1000),
        read_only=True,
    ),
    ParamSpec("sync_slop_s", 0.02, "max stamp difference of a synchronised set (s); 0 = exact", bounds=(0.0, 1.0)),
    ParamSpec(
        "use_semantics", True, "subscribe semantic/image (class-id labels, fused when they come)", read_only=True
    ),
    ParamSpec("depth_scale", 1000.0, "16UC1 depth units per metre (1000 = mm)", bounds=(1.0, 100000.0)),
    ParamSpec(
        "downscale",
        0.0,
        "processing size: divide the width and height of colour, depth, labels and camera_info by this "
        "(as sgs-slam run --downscale; 4 turns 640x480 into 160x120); 0 = auto: on a CPU the factor that "
        "makes the width 160 px (never above the camera's), on a GPU 1",
        bounds=(0.0, 16.0),
        read_only=True,
        zero_is="auto",
    ),
    ParamSpec(
        "lockstep", False, "process every frame in order (replays, tests); else keep up by dropping", read_only=True
    ),
    ParamSpec("stale_input_s", 5.0, "/diagnostics warns when an input is silent this long (s)", bounds=(0.5, 3600.0)),
)
TRACKING = (
    ParamSpec(
        "map_source",
        "shared",
        "'shared' (composed slam_node) or 'topic' (follow ~/gaussians of a mapping node)",
        choices=("shared", "topic"),
        read_only=True,
    ),
    ParamSpec(
        "forward_frames",
        False,
        "publish each accepted frame at the processing size on ~/frames/* (colour, 32FC1 depth, camera_info, "
        "labels) for a mapping_node on another computer (its frame_source:=tracking_node)",
        read_only=True,
    ),
    ParamSpec("path_max_length", 10000, "poses kept in ~/path", bounds=(1, 1000000)),
    ParamSpec(
        "path_rate_hz",
        1.0,
        "max rate of ~/path (after a new pose; 0 = off): each publication carries the whole path",
        bounds=(0.0, 60.0),
    ),
    ParamSpec(
        "map_alignment",
        MapAlignment.FLOOR.value,
        "map frame: 'floor' (z up, levelled on the first frame's floor, origin on the floor; 'mount' if "
        "none is seen), 'mount' (z up: the first pose of base_frame, camera at camera_mount), 'optical' "
        "(the first camera's optical frame, y down)",
        choices=tuple(a.value for a in MapAlignment),
        read_only=True,
    ),
    ParamSpec(
        "camera_mount",
        list(OPTICAL_IN_BODY),
        "pose of the camera optical frame in base_frame: x y z (m) roll pitch yaw (rad), or x y z qx qy qz qw; "
        "the default is a level, forward-looking camera",
        read_only=True,
    ),
    ParamSpec(
        "floor_max_tilt_deg",
        30.0,
        "floor levelling: max angle between the floor and camera_mount's up (deg)",
        bounds=(1.0, 89.0),
        read_only=True,
    ),
    ParamSpec("publish_tf", True, "publish /tf (map -> camera, or map -> odom -> base_frame) and /tf_static"),
    ParamSpec(
        "base_frame", "", "body frame the camera is mounted on ('' = none: /tf is map -> camera)", read_only=True
    ),
    ParamSpec(
        "publish_camera_mount",
        True,
        "publish base_frame -> camera (camera_mount) on /tf_static; false when the camera driver does (realsense)",
        read_only=True,
    ),
    ParamSpec(
        "odom_frame",
        "",
        "with base_frame: publish map -> odom (identity) -> base_frame ('' = map -> base_frame)",
        read_only=True,
    ),
)
MAPPING = (
    ParamSpec(
        "pose_source",
        "shared",
        "'shared' (composed slam_node) or 'topic' (subscribe pose)",
        choices=("shared", "topic"),
        read_only=True,
    ),
    ParamSpec(
        "frame_source",
        "camera",
        "with pose_source:=topic: 'camera' (subscribe the camera topics) or 'tracking_node' (the frames it "
        "forwards at the processing size, tracking_node/frames/*: far less traffic between computers)",
        choices=("camera", "tracking_node"),
        read_only=True,
    ),
    ParamSpec(
        "render_rate_hz", 2.0, "max rate of ~/render/* (one render per newly mapped frame; 0 = off)", bounds=(0.0, 60.0)
    ),
    ParamSpec("points_rate_hz", 1.0, "max rate of ~/points (after the map changed; 0 = off)", bounds=(0.0, 30.0)),
    ParamSpec(
        "gaussians_rate_hz",
        0.5,
        "max rate of ~/gaussians (after the map changed; 0 = only after edits and loads; every frame in lockstep)",
        bounds=(0.0, 30.0),
    ),
    ParamSpec("points_max", 200000, "max points in ~/points (random subset beyond)", bounds=(100, 10000000)),
    ParamSpec(
        "map_path",
        "",
        "the map file of ~/save_map, ~/load_map, autosaves and the save at shutdown "
        "('' = $ROS_HOME/sgs_slam/map.sgsmap, ROS_HOME defaulting to ~/.ros)",
    ),
    ParamSpec(
        "autosave_period_s",
        0.0,
        "seconds between saves of the map to map_path while it changes, written in turns with tracking (0 = off)",
        bounds=(0.0, 86400.0),
        read_only=True,
    ),
    ParamSpec(
        "save_on_shutdown",
        True,
        "on SIGINT/SIGTERM: finish the frames in hand, then save the map to map_path if it changed",
        read_only=True,
    ),
    ParamSpec(
        "load_map_on_start",
        False,
        "load map_path at start when it exists and relocalize in it before mapping (resume after a stop or crash)",
        read_only=True,
    ),
)
EDIT = (  # read when ~/apply_edit is called
    ParamSpec("edit.remove_labels", [], "classes (names or ids) that ~/apply_edit removes", string_list=True),
    ParamSpec("edit.move_label", "", "class (name or id) that ~/apply_edit moves ('' = none)"),
    ParamSpec("edit.translation", [0.0, 0.0, 0.0], "translation of edit.move_label in the map frame (m, x y z)"),
    ParamSpec("edit.rotation_deg", [0.0, 0.0, 0.0], "rotation of edit.move_label about its centroid (deg, x y z)"),
    ParamSpec(
        "edit.instance",
        -1,
        "edit only the K-th connected object of the class (0 = largest, -1 = all)",
        bounds=(-1, 1000),
    ),
)


def _descriptor(spec: ParamSpec) -> ParameterDescriptor:
    text = spec.description + (f" (one of: {', '.join(spec.choices)})" if spec.choices else "")
    # rclpy infers BYTE_ARRAY from an empty list and cannot declare a typed empty STRING_ARRAY
    # (ros2/rclpy#912): string lists are dynamically typed and checked by NodeParams instead.
    d = ParameterDescriptor(description=text, read_only=spec.read_only, dynamic_typing=spec.string_list)
    if spec.bounds is not None and isinstance(spec.default, float):
        d.floating_point_range = [FloatingPointRange(from_value=spec.bounds[0], to_value=spec.bounds[1], step=0.0)]
    elif spec.bounds is not None and isinstance(spec.default, int) and not isinstance(spec.default, bool):
        d.integer_range = [IntegerRange(from_value=int(spec.bounds[0]), to_value=int(spec.bounds[1]), step=1)]
    return d


def _string_list(spec: ParamSpec, value: Any) -> list[str]:
    """A string-list parameter's value: a list of strings, one string (split on whitespace), or empty."""
    if isinstance(value, str):
        return value.split()
    if isinstance(value, (list, tuple)) and all(isinstance(v, str) for v in value):
        return [v for v in value if v.strip()]
    if isinstance(value, (list, tuple, bytes)) and len(value) == 0:
        return []
    raise ParameterError(f"parameter {spec.name}: expected a list of strings, got {value!r}")


def _check(spec: ParamSpec, value: Any) -> Any:
    """The usable value of ``spec`` or :class:`ParameterError` (what rclpy itself does not check)."""
    if spec.string_list:
        return _string_list(spec, value)
    if spec.choices and value not in spec.choices:
        raise ParameterError(f"parameter {spec.name}: {value!r} is not one of {', '.join(spec.choices)}")
    if isinstance(value, float) and not math.isfinite(value):
        raise ParameterError(f"parameter {spec.name}: {value} is not a finite number")
    if spec.zero_is is not None and 0 < value < 1:
        raise ParameterError(f"parameter {spec.name}: {value:g} is neither 0 ({spec.zero_is}) nor at least 1")
    return value


def _integers_as_floats(node: Node, specs: tuple[ParamSpec, ...]) -> None:
    """Start-up values written as integers (``downscale:=2``) for floating-point parameters, as those numbers.

    rclpy refuses an INTEGER value for a DOUBLE parameter, and users write integers. Node's
    ``_parameter_overrides`` are the start-up values (rclpy has no public way to them before
    declaring); without it nothing changes and rclpy's refusal stands.
    """
    overrides = getattr(node, "_parameter_overrides", None)
    if not isinstance(overrides, dict):
        return
    for spec in specs:
        given = overrides.get(spec.name)
        if isinstance(spec.default, float) and given is not None and given.type_ == Parameter.Type.INTEGER:
            overrides[spec.name] = Parameter(spec.name, Parameter.Type.DOUBLE, float(given.value))


def _type_hint(spec: ParamSpec, err: ParameterException) -> str:
    if isinstance(spec.default, float):
        return f"parameter {spec.name}: expected a number like {spec.default!r}"
    kind = type(spec.default).__name__
    return f"parameter {spec.name}: expected {kind} like {spec.default!r} ({err})"


class NodeParams:
    """Declares ``specs`` on a node, keeps ``values`` current, and applies live changes.

    ``on_change[name](value)`` runs after a successful ``set`` of ``name`` (read-only parameters
    cannot be set). A set that fails validation is refused with the reason.
    """

    def __init__(self, node: Node, specs: tuple[ParamSpec, ...]) -> None:
        self.node = node
        self.specs = {s.name: s for s in specs}
        self.values: dict[str, Any] = {}
        self.on_change: dict[str, Callable[[Any], None]] = {}
        _integers_as_floats(node, specs)
        for spec in specs:
            try:
                declared = node.declare_parameter(spec.name, spec.default, _descriptor(spec)).value
            except ParameterException as err:  # wrong type or out of range: one clear line
                if isinstance(err, InvalidParameterTypeException):
                    raise ParameterError(_type_hint(spec, err)) from err
                if spec.bounds is not None and isinstance(err, InvalidParameterValueException):
                    lo, hi = spec.bounds
                    raise ParameterError(f"parameter {spec.name}: out of range (allowed: {lo} to {hi})") from err
                raise ParameterError(f"parameter {spec.name}: {err}") from err
            self.values[spec.name] = _check(spec, declared)
        node.add_on_set_parameters_callback(self._validate)
        node.add_post_set_parameters_callback(self._apply)

    def __getitem__(self, name: str) -> Any:
        return self.values[name]

    def __contains__(self, name: object) -> bool:
        return name in self.values

    def _validate(self, params: list[Parameter]) -> SetParametersResult:
        for p in params:
            spec = self.specs.get(p.name)
            if spec is None:
                continue
            try:
                _check(spec, p.value)
            except ParameterError as err:
                return SetParametersResult(successful=False, reason=str(err))
        return SetParametersResult(successful=True)

    def _apply(self, params: list[Parameter]) -> None:
        for p in params:
            spec = self.specs.get(p.name)
            if spec is None:
                continue
            self.values[p.name] = _check(spec, p.value)
            hook = self.on_change.get(p.name)
            if hook is not None:
                hook(self.values[p.name])


def declare(node: Node, specs: tuple[ParamSpec, ...]) -> NodeParams:
    """Declare ``specs`` on ``node``; a bad value given at start-up raises :class:`ParameterError`."""
    return NodeParams(node, specs)


def use_threads(values: NodeParams) -> None:
    """Set torch's CPU threads for this process from the ``threads`` parameter (0: leave torch's default)."""
    if values["threads"] > 0:
        torch.set_num_threads(values["threads"])


def slam_config(values: NodeParams) -> SlamConfig:
    """The core config from the node's parameters (preset, file, overrides, device, and a tracker's map frame).

    Live nodes (not ``lockstep``) take the config's live variant (``live.overlay``).
    """
    overrides = [*values["overrides"], f"device={values['device']}"]
    if "map_alignment" in values:  # the tracking node's parameters choose the map frame
        overrides += [
            f"map_frame.alignment={values['map_alignment']}",
            f"map_frame.camera_mount={list(values['camera_mount'])}",
            f"map_frame.floor_max_tilt_deg={values['floor_max_tilt_deg']}",
        ]
    config = load_config(values["preset"], values["config_file"] or None, overrides)
    return config if values["lockstep"] else config.for_live()
