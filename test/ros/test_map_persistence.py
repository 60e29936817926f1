"""slam_node's map outlives the process: autosaves survive SIGKILL, SIGINT saves what was mapped, a restart resumes."""

from __future__ import annotations

import dataclasses
import random
import signal
import subprocess

import numpy as np
import pytest
from std_srvs.srv import Trigger

from msg_adapters import pose_to_c2w
from sgs_slam_core.mapio import load_map
from sgs_slam_core.metrics import ate

from ..polling import wait_for
from ..robustness.fakefs import make_read_only
from ..slam.views import room_frame
from .helpers import FAST, Feeder, Spinner, diagnostics_of, new_context, node_params, watched_slam
from .test_two_processes import start

pytestmark = pytest.mark.ros

OVERRIDES = [*FAST, "keyframes.every=3"]  # keyframes near every place, as relocalization after a restart needs
FRAME_NS = 33_333_333


def frame(i: int, n: int):
    """Room frame ``i`` as the ``n``-th frame of the stream (stamped at 30 Hz)."""
    return dataclasses.replace(room_frame(i), stamp_ns=(n + 1) * FRAME_NS, index=n)


def node(domain: int, *params: str) -> subprocess.Popen:
    return start("sgs_slam_ros.slam_node", domain, *params, overrides=OVERRIDES)


def feed(feeder: Feeder, frames: list, proc: subprocess.Popen) -> None:
    """Publish each frame once the previous one's pose came back."""
    assert wait_for(lambda: feeder.connected() or proc.poll() is not None, 90.0) and proc.poll() is None, "no node"
    for f in frames:
        feeder.publish(f)
        assert wait_for(lambda f=f: f.stamp_ns in feeder.poses, 60.0), f"no pose for frame {f.index}"


def finish(proc: subprocess.Popen, sig: int = signal.SIGINT) -> str:
    proc.send_signal(sig)
    try:
        return proc.communicate(timeout=60)[0]
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.communicate()[0]


def autosaved_frames(path) -> int:
    """Frames in the map file at ``path`` (0: none yet); autosaves replace it whole, so it always loads."""
    return len(load_map(path).trajectory) if path.exists() else 0


class Camera:
    """A feeder on its own DDS domain, spinning (a node killed with SIGKILL stays matched until its lease ends)."""

    def __init__(self) -> None:
        self.domain = random.randint(1, 100)
        self.ctx = new_context(self.domain)
        self.feeder = Feeder(self.ctx)
        self.spinner = Spinner(self.ctx, [self.feeder])

    def close(self) -> None:
        self.spinner.stop()
        self.feeder.destroy_node()
        self.ctx.try_shutdown()


def test_sigkill_leaves_the_last_autosave_and_a_restart_goes_on_in_its_map_frame(tmp_path):
    path = tmp_path / "maps" / "m.sgsmap"
    cameras = [Camera()]
    procs, logs = [node(cameras[0].domain, f"map_path:={path}", "autosave_period_s:=0.2")], []
    try:
        feeder = cameras[0].feeder
        feed(feeder, [frame(i, i) for i in range(6)], procs[0])
        # the first autosave may hold fewer frames than were fed; wait for one with all six
        assert wait_for(lambda: autosaved_frames(path) >= 6, 30.0), "no autosave of six frames within 30 s"
        feed(feeder, [frame(i, i) for i in range(6, 9)], procs[0])
        procs[0].kill()  # SIGKILL: no handler runs, whatever the node was doing
        logs.append(procs[0].communicate(timeout=30)[0])
        first_poses = dict(feeder.poses)
        saved = load_map(path)  # complete and loadable
        assert 6 <= len(saved.trajectory) <= 9 and len(saved.gaussians) > 0 and saved.keyframe_images
        assert [s for _, s, _ in saved.trajectory] == sorted(first_poses)[: len(saved.trajectory)]

        cameras.append(Camera())
        feeder = cameras[1].feeder
        procs.append(node(cameras[1].domain, f"map_path:={path}", "load_map_on_start:=true", "save_on_shutdown:=false"))
        resumed = [frame(i, n) for n, i in enumerate(range(10, 16), start=9)]  # the camera moved on meanwhile
        feed(feeder, resumed, procs[1])
        logs.append(finish(procs[1]))
    finally:
        for camera in cameras:
            camera.close()
        logs += [finish(p, signal.SIGKILL) for p in procs[len(logs) :]]
        print("\n---- node logs ----\n" + "\n----\n".join(logs))  # pytest shows it when the test fails
    assert procs[1].returncode == 0, logs[1]
    assert "loaded" in logs[1] and "relocalized in it" in logs[1] and "relocalized at" in logs[1]
    assert load_map(path).trajectory[-1][1] == saved.trajectory[-1][1]  # no save at shutdown: the autosave
    # one trajectory in one map frame: the first run's poses and the resumed ones, aligned together
    truth = {f.stamp_ns: f.gt_c2w for f in [*(frame(i, i) for i in range(9)), *resumed]}
    poses = {s: pose_to_c2w(m) for s, m in [*first_poses.items(), *feeder.poses.items()]}
    stamps = sorted(poses)
    both = ate(np.stack([poses[s] for s in stamps]), np.stack([truth[s] for s in stamps]))
    assert both.rmse < 0.02, f"ATE {100 * both.rmse:.1f} cm over both runs"
    assert len(feeder.poses) == len(resumed)


def test_sigint_saves_every_frame_mapped_before_it(tmp_path):
    path, camera = tmp_path / "m.sgsmap", Camera()
    proc = node(camera.domain, f"map_path:={path}")  # no autosave: only the save at shutdown writes
    try:
        feed(camera.feeder, [frame(i, i) for i in range(7)], proc)
        log = finish(proc)  # at once: the last frame is still being mapped
    finally:
        camera.close()
        if proc.poll() is None:
            finish(proc, signal.SIGKILL)
    assert proc.returncode == 0, log
    saved = load_map(path)
    assert [s for _, s, _ in saved.trajectory] == sorted(camera.feeder.poses) and saved.frames_processed == 7
    assert "frames_mapped 7" in log and "at shutdown: saved" in log, log


def test_an_unreadable_map_at_start_stops_the_node_with_one_line_and_is_left_alone(tmp_path):
    path = tmp_path / "m.sgsmap"
    path.write_bytes(b"not a map at all")
    proc = node(random.randint(1, 100), f"map_path:={path}", "load_map_on_start:=true")
    log = proc.communicate(timeout=120)[0]
    assert proc.returncode == 1, log
    errors = [line for line in log.splitlines() if "error:" in line]
    assert len(errors) == 1 and "not a map" in errors[0] and "load_map_on_start:=false" in errors[0], log
    assert "Traceback" not in log and path.read_bytes() == b"not a map at all"


def test_autosaves_into_a_read_only_folder_are_logged_once_counted_and_keep_the_old_file(tmp_path, monkeypatch):
    path = tmp_path / "maps" / "m.sgsmap"
    path.parent.mkdir()
    path.write_bytes(b"yesterday's map")
    make_read_only(path.parent, monkeypatch)
    params = node_params(overrides=OVERRIDES, map_path=str(path), autosave_period_s=0.1, save_on_shutdown=False)
    slam = watched_slam(params)
    try:
        assert wait_for(slam.feeder.connected, 30.0)
        for i in range(3):
            slam.feeder.publish(frame(i, i))
            assert wait_for(lambda i=i: frame(i, i).stamp_ns in slam.feeder.poses, 60.0)
        mapping = slam.nodes[1]
        assert wait_for(lambda: mapping.saver.stats.failures >= 3, 30.0)  # one an autosave period, while it changes

        def reported() -> bool:
            found = diagnostics_of(slam.diagnostics, "mapping_node")
            return bool(found) and found[-1][2]["map_save_failures"] != "0"

        assert wait_for(reported, 10.0)
        level, message, values = diagnostics_of(slam.diagnostics, "mapping_node")[-1]
        assert level == 1 and "Read-only file system" in message and values["map_saves"] == "0"
        answer = mapping._save_map(Trigger.Request(), Trigger.Response())
        assert not answer.success and "Read-only file system" in answer.message
    finally:
        slam.shut_down()
    errors = [m.msg for m in slam.logs if "Read-only file system" in m.msg]
    assert len(errors) == 1 and "previous map file is kept" in errors[0]
    assert path.read_bytes() == b"yesterday's map"
