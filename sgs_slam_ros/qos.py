"""QoS profiles by name (a string parameter, as users of nvblox and rtabmap expect)."""

from __future__ import annotations

from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)

__all__ = ["INPUT_QOS_CHOICES", "input_qos", "latched_qos", "output_qos"]

INPUT_QOS_CHOICES = ("best_effort", "reliable", "sensor_data", "reliable_all")


def input_qos(name: str, depth: int) -> QoSProfile:
    """Subscriber QoS for images.

    ``best_effort`` (default) matches RealSense-style best-effort publishers *and* reliable ones
    (a bag player); ``reliable`` refuses best-effort publishers but never loses frames between
    processes; ``sensor_data`` is ROS's preset (best effort, depth 5); ``reliable_all`` keeps every
    message (KEEP_ALL), for replays that must not drop frames.
    """
    if name == "best_effort":
        return QoSProfile(depth=depth, reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST)
    if name == "reliable":
        return QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
    if name == "sensor_data":
        return qos_profile_sensor_data
    if name == "reliable_all":
        return QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_ALL)
    raise ValueError(f"input_qos must be one of {', '.join(INPUT_QOS_CHOICES)}, got {name!r}")


def output_qos(depth: int = 5) -> QoSProfile:
    """Publisher QoS: reliable (also serves best-effort subscribers such as RViz)."""
    return QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)


def latched_qos() -> QoSProfile:
    """Reliable + transient local, depth 1: late joiners get the last message (the Gaussian map)."""
    return QoSProfile(
        depth=1,
        reliability=ReliabilityPolicy.RELIABLE,
        history=HistoryPolicy.KEEP_LAST,
        durability=DurabilityPolicy.TRANSIENT_LOCAL,
    )
