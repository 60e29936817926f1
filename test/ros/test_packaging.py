"""The ament_python package: a real colcon build, package.xml dependencies, the RViz and RealSense files."""

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from catkin_pkg.package import parse_package

from sgs_slam_ros.slam_node import build_slam_nodes

from .helpers import new_context, shut_down

pytestmark = pytest.mark.ros
REPO = Path(__file__).resolve().parents[2]
SKIP = shutil.ignore_patterns(".*", "build", "install", "log", "runs", "__pycache__", "*.egg-info", "demo_out")
EXECUTABLES = ("slam_node", "tracking_node", "mapping_node", "bag_player", "segmentation_node")

# setup.py install_requires -> the rosdep key package.xml lists for it
ROSDEP_KEY = {
    "numpy": "python3-numpy",
    "torch": "python3-torch",
    "opencv-python-headless": "python3-opencv",
    "pyyaml": "python3-yaml",
    "rosbags": "python3-rosbags-pip",
    "mcap": "python3-mcap",
    "mcap-ros2-support": "mcap-ros2-support",
    "zstandard": "python3-zstandard",
    "lz4": "python3-lz4",
    "ninja": "ninja-build",
    "matplotlib": "python3-matplotlib",
    "tqdm": "python3-tqdm",
}


def test_colcon_builds_the_package_into_a_workspace(tmp_path):
    """``colcon build`` as a ROS user runs it; the executables land where ``ros2 run`` looks."""
    src = tmp_path / "ws" / "src" / "sgs_slam_ros"
    shutil.copytree(REPO, src, ignore=SKIP)
    ws = tmp_path / "ws"
    colcon = Path(sys.executable).with_name("colcon")
    proc = subprocess.run(
        [str(colcon), "build", "--merge-install", "--event-handlers", "console_direct-"],
        cwd=ws,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "Finished <<< sgs_slam_ros" in proc.stdout
    install = ws / "install"
    for exe in EXECUTABLES:
        path = install / "lib" / "sgs_slam_ros" / exe
        assert path.is_file() and os.access(path, os.X_OK), exe
    share = install / "share" / "sgs_slam_ros"
    assert (install / "share" / "ament_index" / "resource_index" / "packages" / "sgs_slam_ros").is_file()
    for name in ("package.xml", "rviz/sgs_slam.rviz", "config/realsense.yaml", "config/fastdds_shm.xml"):
        assert (share / name).is_file(), name
    # the installed entry point runs the installed code (a bad parameter: it answers and exits 1)
    site = next((install / "lib").glob("python3*/site-packages"))
    env = dict(os.environ, PYTHONPATH=str(site), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    env.pop("_ROS_WHEELS_BOOTSTRAP_COMPLETE", None)
    run = subprocess.run(
        [str(install / "lib" / "sgs_slam_ros" / "slam_node"), "--ros-args", "-p", "preset:=nope"],
        env=env,
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert run.returncode == 1 and "slam_node: error: unknown preset 'nope'" in run.stderr, run.stderr
    where = subprocess.run(
        [sys.executable, "-c", "import sgs_slam_ros; print(sgs_slam_ros.__file__)"],
        env=env,
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    assert where.stdout.strip().startswith(str(site))


def test_package_xml_lists_every_runtime_dependency():
    pkg = parse_package(str(REPO))
    assert pkg.name == "sgs_slam_ros" and pkg.get_build_type() == "ament_python"
    setup = (REPO / "setup.py").read_text()
    assert f'version="{pkg.version}"' in setup
    block = setup[setup.index("install_requires=[") : setup.index("],", setup.index("install_requires=["))]
    required = {re.split(r"[<>=\[]", r)[0] for r in re.findall(r'"([^"]+)"', block)}
    assert required == set(ROSDEP_KEY), "a new requirement needs its rosdep key here and in package.xml"
    depends = {d.name for d in pkg.exec_depends}
    assert {ROSDEP_KEY[r] for r in required} <= depends
    # every ROS package the code imports
    imported = set()
    for path in (REPO / "sgs_slam_ros").glob("*.py"):
        imported |= set(
            re.findall(r"^from (\w+_msgs|\w+_srvs|rclpy|rcl_interfaces|builtin_interfaces)\b", path.read_text(), re.M)
        )
    imported.add("tf2_msgs")  # imported by name in sgs_slam_ros/tf.py
    assert imported <= depends, imported - depends
    assert parse_package(str(REPO / "vendor" / "tf2_msgs")).name == "tf2_msgs"


def rviz_topics(node: dict) -> list[tuple[str, str]]:
    """(topic, durability) of every display in an RViz config."""
    found = []
    for display in node.get("Displays", []):
        topic = display.get("Topic")
        if isinstance(topic, dict):
            found.append((topic["Value"], topic.get("Durability Policy", "Volatile")))
        found += rviz_topics(display)
    return found


def test_the_rviz_view_shows_what_slam_node_publishes():
    config = yaml.safe_load((REPO / "rviz" / "sgs_slam.rviz").read_text())
    manager = config["Visualization Manager"]
    assert manager["Global Options"]["Fixed Frame"] == "map"
    assert any(d["Class"] == "rviz_default_plugins/TF" for d in manager["Displays"])
    ctx = new_context()
    nodes = build_slam_nodes(context=ctx)
    try:
        published = {p.topic_name: p.qos_profile.durability.name for n in nodes for p in n.publishers}
        topics = rviz_topics(manager)
        ours = [(t, d) for t, d in topics if not t.startswith("/camera/")]  # the camera driver's topics
        assert len(ours) >= 5
        for topic, durability in ours:
            assert topic in published, topic
            assert durability.replace(" ", "_").upper() == published[topic], topic  # latched where we latch
    finally:
        shut_down(ctx, nodes)


def test_realsense_params_file_configures_both_nodes():
    ctx = new_context()
    path = REPO / "config" / "realsense.yaml"
    nodes = build_slam_nodes(context=ctx, cli_args=["--ros-args", "--params-file", str(path)])
    try:
        tracking = nodes[0]
        for node in nodes:
            assert node.params["use_semantics"] is False and node.params["preset"] == "tum"
            assert node.params["input_qos"] == "best_effort"
        assert tracking.params["base_frame"] == "camera_link" and not tracking.params["publish_camera_mount"]
        assert tracking.mount[1, 3] == pytest.approx(0.015)
        subscribed = {s.topic_name for s in tracking.subscriptions}
        assert "/rgb/image" in subscribed and "/semantic/image" not in subscribed
    finally:
        shut_down(ctx, nodes)
