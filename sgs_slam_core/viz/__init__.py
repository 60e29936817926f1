"""Pictures of runs: matplotlib plots of trajectories and rendered frames."""

from sgs_slam_core.viz.render_panels import RenderPanel, save_render_panels
from sgs_slam_core.viz.trajectory_plot import plot_trajectory

__all__ = ["RenderPanel", "plot_trajectory", "save_render_panels"]
