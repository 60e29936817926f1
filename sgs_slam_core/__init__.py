"""SGS-SLAM core: semantic Gaussian-splatting SLAM without ROS.

Importing this package never imports rclpy, never touches CUDA and never compiles anything.
"""

from sgs_slam_core.config import SlamConfig, load_config
from sgs_slam_core.errors import (
    BackendUnavailableError,
    ConfigError,
    DatasetError,
    FrameError,
    MapFileError,
    SgsSlamError,
    ShapeError,
)
from sgs_slam_core.frame import Frame
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.geometry import Intrinsics
from sgs_slam_core.kernels import render
from sgs_slam_core.labels import LabelClass, LabelTable
from sgs_slam_core.render import RenderOutput, RenderSettings
from sgs_slam_core.semantics import SemanticCodec, SemanticSettings
from sgs_slam_core.slam.system import Slam, StepResult

__version__ = "0.1.0"

__all__ = [
    "BackendUnavailableError",
    "ConfigError",
    "DatasetError",
    "Frame",
    "FrameError",
    "GaussianMap",
    "Intrinsics",
    "LabelClass",
    "LabelTable",
    "MapFileError",
    "RenderOutput",
    "RenderSettings",
    "SemanticCodec",
    "SemanticSettings",
    "SgsSlamError",
    "ShapeError",
    "Slam",
    "SlamConfig",
    "StepResult",
    "__version__",
    "load_config",
    "render",
]
