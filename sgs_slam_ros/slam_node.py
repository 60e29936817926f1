"""``slam_node``: tracking_node and mapping_node in one process, sharing one map in memory.

The default way to run: no map is serialised between tracking and mapping, and tracking of the
next frame overlaps with mapping of the previous one (live mode). ``python -m
sgs_slam_ros.slam_node`` works as well as the console script.
"""

from __future__ import annotations

from rclpy.node import Node

from sgs_slam_ros.mapping_node import MappingNode
from sgs_slam_ros.runtime import run_nodes
from sgs_slam_ros.tracking_node import TrackingNode

__all__ = ["build_slam_nodes", "main"]


def build_slam_nodes(**node_kwargs: object) -> list[Node]:
    """The composed pair: the tracking node owns the pipeline, the mapping node shares it.

    A ``~/reset`` of either node resets the shared pipeline and both nodes' state.
    """
    tracking = TrackingNode(standalone=False, **node_kwargs)
    try:
        mapping = MappingNode(pipeline=tracking.pipeline, camera_frame=tracking.camera_frame, **node_kwargs)
    except Exception:
        tracking.close()
        tracking.destroy_node()
        raise
    tracking.reset_listeners.append(mapping.after_reset)
    mapping.reset_listeners.append(tracking.after_reset)
    return [tracking, mapping]


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run sgs_slam_ros slam_node``."""
    return run_nodes(build_slam_nodes, args)


if __name__ == "__main__":
    raise SystemExit(main())
