"""Node parameters: one declaration each, with a description, a range or choices, and a default.

All core settings are reachable through ``preset``, ``config_file`` and ``overrides`` (``key=value``
strings, e.g. ``tracking.iterations=30``), resolved exactly like ``sgs-slam run``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import ParameterUninitializedException
from rclpy.node import Node
from rclpy.parameter import Parameter

from sgs_slam_core.config import SlamConfig, load_config
from sgs_slam_ros.qos import INPUT_QOS_CHOICES

__all__ = ["COMMON", "EDIT", "MAPPING", "TRACKING", "ParamSpec", "current", "declare", "slam_config"]


@dataclass(frozen=True)
class ParamSpec:
    """One ROS parameter."""

    name: str
    default: Any
    description: str
    bounds: tuple[float, float] | None = None
    choices: tuple[str, ...] | None = None
    read_only: bool = False
    kind: Parameter.Type | None = None  # for a default that does not tell the type (an empty array)


COMMON = (
    ParamSpec("preset", "tum", "core config preset: replica, scannet, tum, synthetic, *_fast", read_only=True),
    ParamSpec("config_file", "", "YAML file applied after the preset ('' = none)", read_only=True),
    ParamSpec("device", "auto", "compute device", choices=("auto", "cpu", "cuda"), read_only=True),
    ParamSpec("map_frame", "map", "frame id of poses, paths and clouds", read_only=True),
    ParamSpec("input_qos", "best_effort", "image subscription QoS", choices=INPUT_QOS_CHOICES, read_only=True),
    ParamSpec("sync_queue_size", 10, "messages kept per input for synchronisation", bounds=(1, 1000), read_only=True),
    ParamSpec("sync_slop_s", 0.02, "max stamp difference of a synchronised set (s); 0 = exact", bounds=(0.0, 1.0)),
    ParamSpec("use_semantics", True, "subscribe semantic/image (class-id labels)", read_only=True),
    ParamSpec("depth_scale", 1000.0, "16UC1 depth units per metre (1000 = mm)", bounds=(1.0, 100000.0)),
    ParamSpec(
        "lockstep", False, "process every frame in order (replays, tests); else keep up by dropping", read_only=True
    ),
    ParamSpec("stale_input_s", 5.0, "warn in /diagnostics after this long without input (s)", bounds=(0.5, 3600.0)),
)
TRACKING = (
    ParamSpec(
        "map_source",
        "shared",
        "'shared' (composed slam_node) or 'topic' (follow ~/gaussians of a mapping node)",
        choices=("shared", "topic"),
        read_only=True,
    ),
    ParamSpec("path_max_length", 10000, "poses kept in ~/path", bounds=(1, 1000000)),
)
MAPPING = (
    ParamSpec(
        "pose_source",
        "shared",
        "'shared' (composed slam_node) or 'topic' (subscribe pose)",
        choices=("shared", "topic"),
        read_only=True,
    ),
    ParamSpec("render_rate_hz", 2.0, "rate of ~/render/* (0 = off)", bounds=(0.0, 60.0)),
    ParamSpec("points_rate_hz", 1.0, "rate of ~/points (0 = off)", bounds=(0.0, 30.0)),
    ParamSpec(
        "gaussians_rate_hz",
        0.5,
        "rate of ~/gaussians (0 = only on request; every frame in lockstep)",
        bounds=(0.0, 30.0),
    ),
    ParamSpec("points_max", 200000, "max points in ~/points (random subset beyond)", bounds=(100, 10000000)),
    ParamSpec("map_path", "map.sgsmap", "file used by ~/save_map and ~/load_map"),
)
EDIT = (  # read when ~/apply_edit is called
    ParamSpec(
        "edit.remove_labels", None, "classes (names or ids) that ~/apply_edit removes", kind=Parameter.Type.STRING_ARRAY
    ),
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
    d = ParameterDescriptor(description=text, read_only=spec.read_only)
    if spec.bounds is not None and isinstance(spec.default, float):
        d.floating_point_range = [FloatingPointRange(from_value=spec.bounds[0], to_value=spec.bounds[1], step=0.0)]
    elif spec.bounds is not None and isinstance(spec.default, int) and not isinstance(spec.default, bool):
        d.integer_range = [IntegerRange(from_value=int(spec.bounds[0]), to_value=int(spec.bounds[1]), step=1)]
    return d


def declare(node: Node, specs: tuple[ParamSpec, ...]) -> dict[str, Any]:
    """Declare ``specs`` on ``node`` and return their values; a bad choice raises ``ValueError``."""
    values = {}
    for spec in specs:
        if spec.kind is not None and spec.default is None:
            node.declare_parameter(spec.name, spec.kind, _descriptor(spec))
            values[spec.name] = current(node, spec.name, [])
            continue
        values[spec.name] = node.declare_parameter(spec.name, spec.default, _descriptor(spec)).value
        if spec.choices and values[spec.name] not in spec.choices:
            raise ValueError(f"parameter {spec.name}: {values[spec.name]!r} is not one of {', '.join(spec.choices)}")
    if not node.has_parameter("overrides"):
        node.declare_parameter(
            "overrides",
            Parameter.Type.STRING_ARRAY,
            ParameterDescriptor(description="core config overrides 'section.key=value'", read_only=True),
        )
    values["overrides"] = [s for s in current(node, "overrides", []) if s]
    return values


def current(node: Node, name: str, unset: Any) -> Any:
    """The parameter's value now, ``unset`` if it was declared without a value and never set."""
    try:
        value = node.get_parameter(name).value
    except ParameterUninitializedException:
        return unset
    return unset if value is None else value


def slam_config(values: dict[str, Any]) -> SlamConfig:
    """The core config from the node's parameters (preset, file, overrides, device)."""
    return load_config(
        values["preset"], values["config_file"] or None, [*values["overrides"], f"device={values['device']}"]
    )
