"""Progress bars of the command-line tools (implemented in :mod:`sgs_slam_core.runner.progress`).

They live in the runner so that ``run_offline`` does not import the ``cli`` package (whose
``__init__`` imports every command, and some commands import the runner).
"""

from sgs_slam_core.runner.progress import ProgressBar, SlamProgress

__all__ = ["ProgressBar", "SlamProgress"]
