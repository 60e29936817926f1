"""MapSaver: saves on request and on its own thread, skips an unchanged map, keeps the old file when a save fails."""

from __future__ import annotations

import contextlib
import threading

import numpy as np
import pytest

from sgs_slam_core.config import load_config
from sgs_slam_core.live import SlamPipeline
from sgs_slam_core.live.map_saver import MapSaver
from sgs_slam_core.mapio import load_map
from sgs_slam_core.slam.system import Slam

from ..conftest import FAST_SLAM
from ..mapio.test_map_files import map_file, random_map
from ..robustness.fakefs import FullDisk, make_read_only
from ..slam.views import room_frame


class Maps:
    """A stand-in for the pipeline's snapshot: a new map of ``n`` Gaussians each time it is asked."""

    def __init__(self) -> None:
        self.n = 10
        self.taken = 0

    def __call__(self):
        self.taken += 1
        return map_file(random_map(self.n, 3, False, seed=self.taken))


def test_a_save_writes_a_loadable_map_and_an_unchanged_map_is_not_written_again(tmp_path):
    maps, path = Maps(), tmp_path / "maps" / "m.sgsmap"
    saver = MapSaver(path, maps)
    assert not saver.save(only_if_changed=True).saved and not path.exists()  # nothing mapped yet
    saver.mark_changed()
    outcome = saver.save(only_if_changed=True)
    assert outcome.saved and "10 Gaussians and 7 frames" in outcome.message
    assert len(load_map(path).gaussians) == 10
    assert saver.stats.saves == 1 and saver.stats.last_bytes == path.stat().st_size and saver.stats.last_frames == 7
    assert not saver.save(only_if_changed=True).saved and saver.stats.saves == 1
    maps.n = 20
    assert saver.save().saved and len(load_map(path).gaussians) == 20  # on request: always
    saver.mark_changed()
    saver.mark_saved()  # loaded from the file: the same as it
    assert not saver.save(only_if_changed=True).saved


def test_autosaves_come_on_their_own_thread_while_the_map_changes(tmp_path):
    maps, path = Maps(), tmp_path / "m.sgsmap"
    threads = []

    def take():
        threads.append(threading.current_thread().name)
        return maps()

    saver = MapSaver(path, take, period_s=0.02)
    try:
        saver.mark_changed()
        deadline = threading.Event()
        for _ in range(250):
            if saver.stats.saves:
                break
            deadline.wait(0.02)
        assert saver.stats.saves == 1 and threads == ["sgs-autosave"]
        deadline.wait(0.2)
        assert saver.stats.saves == 1  # unchanged since: not written again
        saver.mark_changed()
        for _ in range(250):
            if saver.stats.saves == 2:
                break
            deadline.wait(0.02)
        assert saver.stats.saves == 2
    finally:
        saver.close()
    assert not any(t.name == "sgs-autosave" for t in threading.enumerate())


@pytest.mark.parametrize("failure", ["full disk", "read-only folder"])
def test_a_failed_save_keeps_the_previous_file_logs_once_and_is_counted(tmp_path, monkeypatch, failure):
    maps, path = Maps(), tmp_path / "maps" / "m.sgsmap"
    infos, errors = [], []
    saver = MapSaver(path, maps, log_info=infos.append, log_error=errors.append)
    assert saver.save().saved
    before = path.read_bytes()
    with monkeypatch.context() as m:
        if failure == "full disk":
            FullDisk(m, budget=1000)
        else:
            make_read_only(path.parent, m)
        maps.n = 30
        saver.mark_changed()
        outcomes = [saver.save(only_if_changed=True) for _ in range(3)]
    assert not any(o.saved for o in outcomes)
    reason = "No space left on device" if failure == "full disk" else "Read-only file system"
    assert len(errors) == 1 and reason in errors[0] and "previous map file is kept" in errors[0]
    assert saver.stats.failures == 3 and reason in saver.stats.last_error
    assert path.read_bytes() == before and len(load_map(path).gaussians) == 10
    assert [p.name for p in path.parent.iterdir()] == ["m.sgsmap"]  # no temporary file left behind
    assert saver.changed  # the change is still to be saved
    assert saver.save(only_if_changed=True).saved and len(load_map(path).gaussians) == 30
    assert len(infos) == 1 and "saving works again" in infos[0] and saver.stats.last_error == ""


def test_a_snapshot_that_cannot_be_taken_is_a_failed_save(tmp_path):
    def busy():
        raise TimeoutError("SLAM workers did not become idle")

    errors = []
    saver = MapSaver(tmp_path / "m.sgsmap", busy, log_error=errors.append)
    outcome = saver.save()
    assert not outcome.saved and "did not become idle" in outcome.message and len(errors) == 1
    with pytest.raises(ValueError, match="period"):
        MapSaver(tmp_path / "m.sgsmap", busy, period_s=-1.0)


def test_the_pipeline_snapshot_is_the_map_as_mapped_and_resumes_in_a_new_pipeline(tmp_path):
    config = load_config("synthetic", overrides=list(FAST_SLAM))
    pipeline = SlamPipeline(Slam(config), lockstep=True)
    try:
        for i in range(4):
            pipeline.submit_frame(room_frame(i))
        assert pipeline.wait_idle(120)
        saver = MapSaver(tmp_path / "m.sgsmap", pipeline.map_file)
        assert saver.save().saved
        saved = load_map(tmp_path / "m.sgsmap")
        assert len(saved.trajectory) == 4 and len(saved.gaussians) == pipeline.slam.num_gaussians
        assert saved.keyframe_images  # relocalization needs them
    finally:
        pipeline.shutdown()
    again = SlamPipeline(Slam(config), lockstep=True)
    try:
        again.load_map(saved)
        again.submit_frame(room_frame(4))
        assert again.wait_idle(120)
        truth = np.linalg.inv(room_frame(0).gt_c2w) @ room_frame(4).gt_c2w
        assert np.linalg.norm(again.slam.trajectory[-1][2][:3, 3] - truth[:3, 3]) < 0.02
        assert again.stats.tracked == 1 and again.stats.mapped == 1
    finally:
        again.shutdown()


def test_a_background_write_runs_in_parts_and_a_save_on_request_in_one(tmp_path):
    parts = []

    @contextlib.contextmanager
    def turn():
        parts.append(1)
        yield

    maps = Maps()
    maps.n = 30000  # a few MiB: several parts
    saver = MapSaver(tmp_path / "m.sgsmap", maps, turn=turn)
    assert saver.save().saved and not parts
    assert saver.save(background=True).saved
    size = (tmp_path / "m.sgsmap").stat().st_size
    assert len(parts) == 1 + -(-size // 2**20)  # the serialising, then each MiB


def test_a_background_turn_waits_for_the_frame_being_tracked_and_holds_the_next_one(tmp_path):
    config = load_config("synthetic", overrides=list(FAST_SLAM))
    pipeline = SlamPipeline(Slam(config), lockstep=False)
    try:
        pipeline.submit_frame(room_frame(0))
        assert pipeline.wait_idle(120)
        with pipeline.background_turn():
            pipeline.submit_frame(room_frame(1))
            assert not pipeline.wait_idle(0.5)  # the frame waits for the turn to end
            assert pipeline.stats.tracked == 1
        assert pipeline.wait_idle(120) and pipeline.stats.tracked == 2
    finally:
        pipeline.shutdown()
    lockstep = SlamPipeline(Slam(config), lockstep=True)
    try:
        with lockstep.background_turn():  # nothing to take turns with: the body just runs
            assert not lockstep._busy["background"]
    finally:
        lockstep.shutdown()
