"""The live pipeline's queue of one, and the realtime replay built on it."""

import json
import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from sgs_slam_core.cli import main
from sgs_slam_core.config import load_config
from sgs_slam_core.config.sections import LiveSettings
from sgs_slam_core.datasets import open_dataset
from sgs_slam_core.errors import ConfigError, DatasetError, FrameError
from sgs_slam_core.labels import LabelTable
from sgs_slam_core.live import MapJob, SlamPipeline
from sgs_slam_core.metrics import read_tum_trajectory
from sgs_slam_core.runner.realtime import RealtimeOptions, _Replay, release_times, run_realtime
from sgs_slam_core.slam.mapper import MapStats
from sgs_slam_core.slam.system import MapOutcome, Slam, TrackOutcome

from ..conftest import FAST_SLAM
from ..polling import wait_for


class GatedSlam:
    """Stands in for Slam: tracking blocks until released, so the test decides what is busy when."""

    def __init__(self, device: str = "cpu", live: LiveSettings | None = None) -> None:
        self.device = torch.device(device)
        # live: a job's turn on the CPU is ceil(20 / 10) = 2 steps; elsewhere it may end after ceil(20 / 3) = 7
        self.config = SimpleNamespace(mapping=SimpleNamespace(iterations=20), live=live or LiveSettings())
        self.frames_processed, self.num_gaussians = 0, 0
        self.gate = threading.Semaphore(0)
        self.tracked: list[int] = []
        self.asks: list = []  # per tracked frame: the newer_frame_waiting it was given

    def track(self, frame, newer_frame_waiting=None):
        self.asks.append(newer_frame_waiting)
        self.gate.acquire()
        self.tracked.append(frame.index)
        self.frames_processed += 1
        return SimpleNamespace(failed=False, index=frame.index, state="ok", lost=False, time_s=0.0)

    def map(self, frame, tracked, between_iterations=None, before_publish=None):
        self.num_gaussians += 1
        return MapOutcome.not_mapped()


class TimedSlam(GatedSlam):
    """Tracking takes 30 ms; mapping runs up to 20 steps of 5 ms; each records whether the other ran."""

    def __init__(self, device: str = "cpu", live: LiveSettings | None = None) -> None:
        super().__init__(device, live)
        self.tracking_now = self.mapping_now = self.job_now = False
        self.steps_during_tracking = self.tracks_during_steps = self.tracks_during_jobs = 0
        self.steps = 0
        self.job_steps: list[int] = []

    def track(self, frame, newer_frame_waiting=None):
        self.tracks_during_steps += int(self.mapping_now)
        self.tracks_during_jobs += int(self.job_now)
        self.tracking_now = True
        time.sleep(0.03)
        self.tracking_now = False
        self.frames_processed += 1
        return SimpleNamespace(failed=False, index=frame.index, state="ok", lost=False, time_s=0.0)

    def map(self, frame, tracked, between_iterations=None, before_publish=None):
        self.num_gaussians += 1
        self.job_now, steps = True, 0
        for _ in range(20):
            if between_iterations is not None and not between_iterations():
                break
            self.steps_during_tracking += int(self.tracking_now)
            self.mapping_now = True
            time.sleep(0.005)
            self.mapping_now = False
            self.steps += 1
            steps += 1
        self.job_steps.append(steps)
        self.job_now = False
        return MapOutcome(MapStats(steps, 0, 0.0, 0.0), None, False, 0, 0.0)


def test_frames_arriving_while_tracking_is_busy_replace_the_waiting_one():
    slam = GatedSlam()
    pipeline = SlamPipeline(slam, lockstep=False, log=lambda _: None)
    try:
        pipeline.submit_frame(SimpleNamespace(index=0))
        assert wait_for(lambda: pipeline._busy["track"], 5.0)  # frame 0 is being tracked
        for i in range(1, 6):  # 1..4 are replaced in turn, 5 waits
            pipeline.submit_frame(SimpleNamespace(index=i))
        for _ in range(2):
            slam.gate.release()
        assert pipeline.wait_idle(5.0)
        assert slam.tracked == [0, 5]
        st = pipeline.stats
        assert (st.frames_in, st.tracked, st.dropped_frames) == (6, 2, 4)
    finally:
        slam.gate.release()
        pipeline.shutdown()


def test_live_on_the_cpu_mapping_steps_never_start_while_a_frame_is_tracked():
    slam = TimedSlam()
    pipeline = SlamPipeline(slam, lockstep=False, log=lambda _: None)
    try:
        for i in range(12):  # a 100 Hz camera: tracking (30 ms) and mapping (100 ms a job) cannot both keep up
            pipeline.submit_frame(SimpleNamespace(index=i))
            time.sleep(0.01)
        assert pipeline.wait_idle(10.0)
        assert slam.steps >= 20 and slam.steps_during_tracking == 0
        assert slam.tracks_during_steps == 0  # a frame waits for the mapping step in progress to end
        assert pipeline.stats.tracked >= 2 and pipeline.stats.mapped >= 1
    finally:
        pipeline.shutdown()


@pytest.mark.parametrize(("floor", "steps"), [(0.0, [0, 0, 0, 0]), (2.0, [2, 2, 2, 2]), (0.5, [1, 0, 1, 0])])
def test_live_on_the_cpu_a_frames_job_makes_the_steps_its_floor_owes_then_ends_for_the_next_frame(floor, steps):
    slam = TimedSlam(live=LiveSettings(min_map_steps=floor))
    pipeline = SlamPipeline(slam, lockstep=False, log=lambda _: None)
    try:
        for i in range(24):  # a 100 Hz camera: a frame always waits once a job has made its turn
            pipeline.submit_frame(SimpleNamespace(index=i))
            time.sleep(0.01)
        assert pipeline.wait_idle(20.0)
        assert slam.tracks_during_jobs == 0  # the next frame meets the map with the last one in it
        assert len(slam.job_steps) >= 5 and slam.job_steps[:4] == steps  # the mean kept at the floor
        assert slam.job_steps[-1] == 20  # nothing waits after the last frame: its job runs to the end
        assert pipeline.stats.dropped_jobs == 0
        assert pipeline.stats.map_steps == sum(slam.job_steps)  # what /diagnostics reports per frame
        assert pipeline.stats.map_steps_per_frame == sum(slam.job_steps) / len(slam.job_steps)
    finally:
        pipeline.shutdown()


@pytest.mark.parametrize("lockstep", [False, True])
def test_with_mapping_on_its_own_stream_a_job_with_a_newer_one_waiting_ends_after_a_third_of_its_steps(lockstep):
    slam = TimedSlam(device="meta")  # not the CPU: the workers do not take turns (as on CUDA, without its stream)
    pipeline = SlamPipeline(slam, lockstep=lockstep, log=lambda _: None)
    try:
        for i in range(12):  # tracking outpaces mapping: a newer job is always waiting
            pipeline.submit_frame(SimpleNamespace(index=i))
            time.sleep(0.01)
        assert pipeline.wait_idle(20.0)
        if lockstep:  # every job runs to the end
            assert slam.job_steps == [20] * 12
        else:  # ceil(20 / 3) = 7 steps when preempted; the last job, with nothing waiting, runs all 20
            assert 7 in slam.job_steps and set(slam.job_steps) <= set(range(7, 21))
            assert slam.job_steps[-1] == 20
    finally:
        pipeline.shutdown()


class RegisteringSlam(TimedSlam):
    """A mapping process's Slam: frames come with their poses from a tracker elsewhere."""

    def register(self, frame, c2w):
        return SimpleNamespace(failed=False, index=frame.index, state="ok", lost=False, time_s=0.0)


def test_a_mapping_process_on_the_cpu_publishes_its_first_map_at_once_and_takes_in_each_newer_frame():
    slam = RegisteringSlam()
    pipeline = SlamPipeline(slam, lockstep=False, track=False, map=True, log=lambda _: None)
    try:
        pipeline.submit_job(MapJob(SimpleNamespace(index=0), c2w=np.eye(4)))
        assert wait_for(lambda: slam.job_steps, 5.0)
        assert slam.job_steps == [1]  # the tracker elsewhere tracks nothing before this map
        for i in range(1, 8):  # jobs come faster than 20 steps: a newer one is always waiting
            pipeline.submit_job(MapJob(SimpleNamespace(index=i), c2w=np.eye(4)))
            time.sleep(0.01)
        assert pipeline.wait_idle(10.0)
        # a job ends one step after a newer one came (beside tracking on a stream: a third, 7 steps)
        assert min(slam.job_steps[1:-1]) <= 2
        assert slam.job_steps[-1] == 20  # the last, with nothing waiting, runs on
    finally:
        pipeline.shutdown()


def test_a_tracking_process_tracks_nothing_before_its_first_map_comes():
    slam = TimedSlam()
    pipeline = SlamPipeline(slam, lockstep=False, track=True, map=False, log=lambda _: None)
    try:
        pipeline.submit_frame(SimpleNamespace(index=0))  # the first frame sets the map frame
        assert wait_for(lambda: slam.frames_processed == 1, 5.0)
        pipeline.submit_frame(SimpleNamespace(index=1))
        assert not wait_for(lambda: slam.frames_processed > 1, 0.3)  # no map yet: its pose would be a guess
        slam.num_gaussians = 10  # the mapper's map came (replace_map)
        pipeline.wake()
        assert wait_for(lambda: slam.frames_processed == 2, 5.0)
    finally:
        pipeline.shutdown()


@pytest.mark.parametrize("lockstep", [False, True])
def test_live_tracking_is_told_when_a_newer_frame_waits(lockstep):
    slam = GatedSlam()
    slam.map = lambda frame, tracked, between_iterations=None: setattr(slam, "num_gaussians", 1)
    pipeline = SlamPipeline(slam, lockstep=lockstep, log=lambda _: None)
    try:
        pipeline.submit_frame(SimpleNamespace(index=0))
        slam.gate.release()
        assert pipeline.wait_idle(5.0)
        pipeline.submit_frame(SimpleNamespace(index=1))
        assert wait_for(lambda: len(slam.asks) >= 2, 5.0)  # frame 1 is being tracked
        ask = slam.asks[-1]
        if lockstep:  # every frame is kept, so tracking never ends early
            assert ask is None
        else:
            assert ask() is False
            pipeline.submit_frame(SimpleNamespace(index=2))  # the camera moves on
            assert ask() is True
        for _ in range(2):
            slam.gate.release()
        assert pipeline.wait_idle(5.0)
    finally:
        slam.gate.release()
        pipeline.shutdown()


class SlowMappingSlam(GatedSlam):
    """Mapping runs 400 steps of 10 ms (4 s) unless the pipeline stops it between steps."""

    def __init__(self) -> None:
        super().__init__()
        self.steps = 0

    def track(self, frame, newer_frame_waiting=None):
        self.frames_processed += 1
        return SimpleNamespace(failed=False, index=frame.index, state="ok", lost=False, time_s=0.0)

    def map(self, frame, tracked, between_iterations=None, before_publish=None):
        for _ in range(400):
            if between_iterations is not None and not between_iterations():
                break
            self.steps += 1
            time.sleep(0.01)
        return MapOutcome(MapStats(self.steps, 0, 0.0, 0.0), None, False, 0, 0.0)


@pytest.mark.parametrize("lockstep", [False, True])
def test_shutdown_stops_mapping_at_its_next_step(lockstep):
    """A second Ctrl-C must not wait for a whole mapping window (minutes at 640x480 on a CPU)."""
    slam = SlowMappingSlam()
    pipeline = SlamPipeline(slam, lockstep=lockstep, log=lambda _: None)
    pipeline.submit_frame(SimpleNamespace(index=0))
    assert wait_for(lambda: slam.steps >= 3, 5.0)
    started = time.monotonic()
    pipeline.shutdown(timeout=10.0)
    assert time.monotonic() - started < 2.0 and slam.steps < 200
    assert not any(t.is_alive() for t in pipeline._threads)
    assert pipeline.stats.mapping_errors == 0 and pipeline.stats.mapped == 0  # abandoned, not failed


def test_finishing_ends_the_mapping_job_at_its_next_step_and_keeps_its_frame():
    """Before exit the frame in hand is mapped; its thousands of refinement steps do not hold the exit."""
    slam = SlowMappingSlam()
    pipeline = SlamPipeline(slam, lockstep=False, log=lambda _: None)
    try:
        pipeline.submit_frame(SimpleNamespace(index=0))
        assert wait_for(lambda: slam.steps >= 3, 5.0)
        started = time.monotonic()
        assert pipeline.finish(10.0)
        assert time.monotonic() - started < 2.0 and slam.steps < 200
        assert pipeline.stats.mapped == 1 and pipeline.stats.mapping_errors == 0  # ended, not abandoned
    finally:
        pipeline.shutdown()


def test_a_reset_never_maps_a_frame_tracked_before_it():
    """The reset waits until the tracked frame is handed over, then drops its mapping job."""
    slam = GatedSlam()
    slam.mapped, slam.resets = [], 0
    slam.map = lambda frame, tracked, between_iterations=None: slam.mapped.append((slam.resets, frame.index))
    slam.reset = lambda: setattr(slam, "resets", slam.resets + 1)
    pipeline = SlamPipeline(slam, lockstep=False, log=lambda _: None)
    publishing, release = threading.Event(), threading.Event()
    pipeline.pose_listeners.append(lambda frame, outcome: (publishing.set(), release.wait(5.0)))
    try:
        pipeline.submit_frame(SimpleNamespace(index=0))
        slam.gate.release()
        assert publishing.wait(5.0)  # frame 0 is tracked; its pose is being published
        resetter = threading.Thread(target=pipeline.reset)
        resetter.start()
        assert not wait_for(lambda: slam.resets, 0.2)  # the reset waits for the hand-over
        release.set()
        resetter.join(5.0)
        assert slam.resets == 1 and pipeline.wait_idle(5.0)
        assert (1, 0) not in slam.mapped  # frame 0 was not mapped into the fresh map
    finally:
        release.set()
        pipeline.shutdown()


def test_lockstep_keeps_every_frame_in_order():
    slam = GatedSlam()
    pipeline = SlamPipeline(slam, lockstep=True, log=lambda _: None)
    try:
        for i in range(4):
            pipeline.submit_frame(SimpleNamespace(index=i))
        for _ in range(4):
            slam.gate.release()
        assert pipeline.wait_idle(5.0)
        assert slam.tracked == [0, 1, 2, 3] and pipeline.stats.dropped_frames == 0
    finally:
        pipeline.shutdown()


def test_release_times_follow_the_stamps_or_the_rate():
    assert np.allclose(release_times([5_000_000_000, 5_100_000_000, 5_300_000_000], None), [0, 0.1, 0.3])
    assert np.allclose(release_times([0, 0, 0], 10.0), [0, 0.1, 0.2])
    with pytest.raises(DatasetError, match="--realtime HZ"):
        release_times([3, 2, 1], None)
    with pytest.raises(DatasetError, match="> 0"):
        release_times([1, 2], 0.0)


def test_realtime_replay_accounts_for_every_frame(tiny_scene):
    dataset = open_dataset(tiny_scene)
    slam = Slam(load_config("synthetic", overrides=list(FAST_SLAM)).for_live(), dataset.label_table)
    # 1 ms apart: faster than any machine tracks (at 100 Hz a fresh CI machine once tracked all 12)
    result = run_realtime(slam, dataset, RealtimeOptions(hz=1000.0))
    st = result.stats
    assert st.frames_in == len(dataset) == st.frames_tracked + st.frames_dropped
    assert st.preloaded_frames == len(dataset)  # 12 small frames: all decoded before the clock
    assert 1 <= st.frames_tracked < len(dataset) and st.frames_mapped >= 1
    assert result.dataset_indices[0] == 0 and result.dataset_indices == sorted(result.dataset_indices)
    assert st.realtime_hz == pytest.approx(1000.0)
    assert all(np.isfinite(s.c2w).all() for s in result.steps)
    # live runs re-decode classes at keyframes only; the replay's end brings them up to date
    assert slam.config.mapping.refresh_labels_keyframes_only and not slam._labels_stale


class _Unreadable:
    """A dataset of the given frames whose frame ``bad`` cannot be read; it records every read."""

    def __init__(self, frames: list, bad: int) -> None:
        self.frames, self.bad, self.reads = frames, bad, []

    def __getitem__(self, i: int):
        self.reads.append(i)
        if i == self.bad:
            raise FrameError("depth PNG truncated")
        return self.frames[i]


def test_a_replay_decodes_ahead_within_its_budget(tiny_scene):
    frames = [open_dataset(tiny_scene)[i] for i in range(6)]
    one = frames[0].nbytes
    replay = _Replay(slam=None, dataset=_Unreadable(frames, bad=1), on_tracked=None)
    replay.preload(6, 3 * one + one // 2, should_stop=lambda: False)
    # frame 1 is unreadable (counted once, kept as None so it is not read again); 0, 2, 3 fit, 4 does not
    assert sorted(replay.ahead) == [0, 1, 2, 3] and replay.ahead[1] is None and replay.preloaded == 4
    assert replay.unreadable == 1 and "truncated" in replay.first_skip
    assert replay.dataset.reads == [0, 1, 2, 3, 4]

    none = _Replay(slam=None, dataset=_Unreadable(frames, bad=-1), on_tracked=None)
    none.preload(6, 0, should_stop=lambda: False)
    assert none.ahead == {} and none.preloaded == 0

    asked = []
    stopped = _Replay(slam=None, dataset=_Unreadable(frames, bad=-1), on_tracked=None)
    stopped.preload(6, 10 * one, should_stop=lambda: asked.append(1) or len(asked) > 2)
    assert stopped.preloaded == 2  # Ctrl-C while decoding ends the decoding


def test_realtime_options_reject_a_negative_preload():
    with pytest.raises(ConfigError, match="preload"):
        RealtimeOptions(preload_mb=-1.0)


def test_a_replay_keeps_poses_not_frames():
    """A long replay must not hold every tracked frame's images (GBs at 640x480 over a sequence)."""
    replay = _Replay(slam=None, dataset=None, on_tracked=None)
    gt = np.eye(4)
    frame = SimpleNamespace(index=7, gt_c2w=gt)
    outcome = TrackOutcome(7, 0, np.eye(4), None, None, 0.01, frame_data=object())
    replay.on_pose(frame, outcome)
    kept_gt, kept = replay.tracked[7]
    assert kept_gt is gt and kept.frame_data is None and kept.c2w is outcome.c2w
    assert outcome.frame_data is not None  # the mapper still gets the tensors


def test_cli_realtime_writes_the_counts(tiny_scene, tmp_path):
    out = tmp_path / "rt"
    sets = [a for o in FAST_SLAM for a in ("--set", o)]
    assert main(["run", str(tiny_scene), "--out", str(out), "--realtime", "20", "--quiet", *sets]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["frames_in"] == 12 and metrics["realtime_hz"] == pytest.approx(20.0)
    assert metrics["preloaded_frames"] == 12
    assert metrics["frames_tracked"] + metrics["frames_dropped"] == 12
    assert 1 <= metrics["map_steps_per_frame"] <= 15  # mapping.iterations=15 at most, live gives fewer
    stamps, _ = read_tum_trajectory(out / "trajectory.txt")
    assert len(stamps) == metrics["frames_tracked"] == metrics["frames"]
    assert load_config(path=out / "config.yaml").tracking.method == "gauss_newton"  # the live tracker, recorded


def test_nodes_reach_the_slam_through_the_pipeline(tiny_scene):
    dataset = open_dataset(tiny_scene)
    slam = Slam(load_config("synthetic", None, [*FAST_SLAM, "device=cpu"]), dataset.label_table)
    pipeline = SlamPipeline(slam, lockstep=True, log=lambda _: None)
    try:
        empty = pipeline.snapshot()
        assert empty.frames_processed == 0 and empty.last_c2w is None and len(empty.gaussians) == 0
        other = LabelTable.nyu40()
        assert pipeline.use_label_table(other) and pipeline.snapshot().codec.table == other  # nothing mapped yet
        pipeline.submit_frame(dataset[0])
        assert pipeline.wait_idle(60.0)
        snap = pipeline.snapshot()
        assert snap.frames_processed == 1 and snap.last_stamp_ns == dataset[0].stamp_ns and len(snap.gaussians) > 0
        assert np.array_equal(snap.last_c2w, slam.trajectory[-1][2]) and snap.last_c2w is not slam.trajectory[-1][2]
        assert not pipeline.use_label_table(dataset.label_table)  # the map has classes now: the table stays
        view = pipeline.render_view(snap, snap.last_c2w)
        assert view.color.shape == (48, 64, 3) and float(view.silhouette.mean()) > 0.5
        pipeline.count_dropped(2)
        assert pipeline.stats.dropped_frames == 2
    finally:
        pipeline.shutdown()


def test_cli_rejects_a_negative_preload(tiny_scene, tmp_path, capsys):
    with pytest.raises(SystemExit) as stop:
        main(["run", str(tiny_scene), "--out", str(tmp_path / "rt"), "--realtime", "--preload-mb", "-1"])
    assert stop.value.code == 2 and "--preload-mb" in capsys.readouterr().err
