"""The dependency rule: only sgs_slam_ros may import rclpy; the core never compiles on import."""

import subprocess
import sys

import pytest

pytestmark = pytest.mark.slow  # fresh interpreters: left out of make test-fast

CHECK = """
import sys, importlib
for name in {modules!r}:
    importlib.import_module(name)
banned = ("rclpy.", "gsplat", "sensor_msgs", "torch.utils.cpp_extension")
bad = sorted(m for m in sys.modules if m == "rclpy" or m.startswith(banned))
print(",".join(bad))
"""


@pytest.mark.parametrize("modules", [["sgs_slam_core"], ["msg_adapters"], ["bags"]])
def test_package_imports_no_rclpy_and_no_compiler(modules):
    out = subprocess.run(
        [sys.executable, "-c", CHECK.format(modules=modules)], capture_output=True, text=True, check=True
    )
    assert out.stdout.strip() == "", f"{modules} imported {out.stdout.strip()}"
