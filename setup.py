"""Install the sgs_slam_ros ament_python package (also a plain pip package)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "sgs_slam_ros"
VIEWER = ["rerun-sdk>=0.41", "foxglove-sdk>=0.30"]  # the APIs used here (tested with 0.41.0 and 0.30.3)

setup(
    name=PACKAGE,
    version="0.1.0",
    description="SGS-SLAM for ROS 2: semantic Gaussian-splatting SLAM with a ROS-free core",
    license="Apache-2.0",
    python_requires=">=3.10",
    packages=find_packages(exclude=["test", "test.*", "bench", "bench.*"]),
    package_data={
        "sgs_slam_core.config": ["presets/*.yaml"],
        "sgs_slam_core.kernels.cpu": ["*.cpp"],
    },
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/rviz", glob("rviz/*.rviz")),
        (f"share/{PACKAGE}/config", glob("config/*.yaml") + glob("config/*.xml")),
    ],
    zip_safe=True,
    install_requires=[
        "numpy>=1.24",
        "torch>=2.4",  # fused Adam on the CPU
        "opencv-python-headless>=4.8",
        "pyyaml>=6",
        "rosbags>=0.11",
        "mcap>=1.1",
        "mcap-ros2-support>=0.5",
        "zstandard",  # bags: zstd MCAP chunks (imported directly, not only through mcap)
        "lz4",  # bags: lz4 MCAP chunks
        "ninja",  # builds the compiled CPU renderer on first use (with the system's g++)
        "matplotlib>=3.7",  # trajectory.png, renders/*.png
        "tqdm>=4.66",  # progress bars
    ],
    extras_require={
        "ros": ["ros-jazzy-rclpy[fastrtps]", "ros-jazzy-common-interfaces"],
        "viewer": VIEWER,  # sgs-slam run --viewer rerun|foxglove
        "lpips": ["lpips>=0.1.4"],  # ships the LPIPS linear layers (the AlexNet backbone is still needed)
        "segmentation": ["transformers>=4.40"],  # segmentation_node: SegFormer (ADE20K) through Hugging Face
        "test": ["pytest>=8", "ruff>=0.6", "evo>=1.28", "colcon-core", "colcon-ros", "catkin_pkg", *VIEWER],
    },
    entry_points={
        "sgs_slam_core.dataset_formats": ["mcap = bags.format:MCAP_FORMAT"],
        "console_scripts": [
            "sgs-slam = sgs_slam_core.cli:main",
            "sgs-slam-bag = bags.cli:main",
            "bag_player = sgs_slam_ros.bag_player:main",
            "slam_node = sgs_slam_ros.slam_node:main",
            "tracking_node = sgs_slam_ros.tracking_node:main",
            "mapping_node = sgs_slam_ros.mapping_node:main",
            "segmentation_node = sgs_slam_ros.segmentation_node:main",
        ],
    },
)
