"""Pictures and live views of runs: matplotlib plots, and Rerun / Foxglove live viewers (optional extras).

Importing this package imports matplotlib but neither rerun nor foxglove; :func:`open_viewer` loads
the chosen backend.
"""

from sgs_slam_core.viz.render_panels import RenderPanel, save_render_panels
from sgs_slam_core.viz.snapshot import ViewerSettings
from sgs_slam_core.viz.trajectory_plot import plot_trajectory
from sgs_slam_core.viz.viewer import VIEWER_KINDS, Viewer, ViewerOptions, kind_of_file, open_viewer

__all__ = [
    "VIEWER_KINDS",
    "RenderPanel",
    "Viewer",
    "ViewerOptions",
    "ViewerSettings",
    "kind_of_file",
    "open_viewer",
    "plot_trajectory",
    "save_render_panels",
]
