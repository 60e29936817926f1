"""Install the sgs_slam_ros ament_python package (also a plain pip package)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "sgs_slam_ros"

setup(
    name=PACKAGE,
    version="0.1.0",
    description="SGS-SLAM for ROS 2: semantic Gaussian-splatting SLAM with a ROS-free core",
    license="Apache-2.0",
    python_requires=">=3.10",
    packages=find_packages(exclude=["test", "test.*", "bench", "bench.*"]),
    package_data={"sgs_slam_core.config": ["presets/*.yaml"], "sgs_slam_core.render": ["cpu/*.cpp"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/rviz", glob("rviz/*.rviz")),
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
    ],
    zip_safe=True,
    install_requires=[
        "numpy>=1.24",
        "torch>=2.1",
        "opencv-python-headless>=4.8",
        "pyyaml>=6",
        "rosbags>=0.11",
        "mcap>=1.1",
        "mcap-ros2-support>=0.5",
        "zstandard",  # bags: zstd MCAP chunks (imported directly, not only through mcap)
        "lz4",  # bags: lz4 MCAP chunks
        "ninja",  # builds the compiled CPU renderer on first use (with the system's g++)
    ],
    extras_require={
        "ros": ["ros-jazzy-rclpy[fastrtps]", "ros-jazzy-common-interfaces"],
        "test": ["pytest>=8", "ruff>=0.6", "evo>=1.28", "colcon-core", "colcon-ros", "catkin_pkg"],
    },
    entry_points={
        "console_scripts": [
            "sgs-slam = sgs_slam_core.cli:main",
            "sgs-slam-bag = bags.cli:main",
            "bag_player = sgs_slam_ros.bag_player:main",
            "slam_node = sgs_slam_ros.slam_node:main",
            "tracking_node = sgs_slam_ros.tracking_node:main",
            "mapping_node = sgs_slam_ros.mapping_node:main",
        ],
    },
)
