"""Device-clean code, proven on the CPU: every CLI path and the nodes with the default device ``meta``."""

import os
import subprocess
import sys

import pytest

from ..conftest import REPO

pytestmark = pytest.mark.ros


def test_every_cli_path_and_the_nodes_make_tensors_on_the_callers_device(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(REPO))
    out = subprocess.run(
        [sys.executable, "-m", "test.devices.meta_driver", str(tmp_path)],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
        check=False,
    )
    assert out.returncode == 0, out.stdout[-6000:] + out.stderr[-4000:]
    assert out.stdout.count("ok: ") == 16, out.stdout
