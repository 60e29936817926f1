"""Frames that never arrived are counted from gaps in the stamps; a busy node judges no input silent."""

import time

import numpy as np

from sgs_slam_ros.activity import Activity
from sgs_slam_ros.inputs import InputWatch
from sgs_slam_ros.stream_gaps import StreamGaps

PERIOD = 33_333_333  # ns: a 30 Hz camera


def feed(gaps: StreamGaps, stamps) -> list:
    return [r for r in (gaps.add(int(s)) for s in stamps) if r is not None]


def test_no_gap_no_loss_with_jitter():
    rng = np.random.default_rng(0)
    stamps = np.arange(300) * PERIOD + rng.integers(-4_000_000, 4_000_000, 300)  # +-4 ms jitter
    gaps = StreamGaps()
    assert feed(gaps, stamps) == [] and gaps.lost == 0 and gaps.received == 300


def test_every_missing_frame_is_counted_even_before_the_period_is_known():
    rng = np.random.default_rng(1)
    kept = np.ones(300, bool)
    kept[[2, 3, 40, 41, 42, 100]] = False  # two of them among the first differences
    kept[rng.choice(np.arange(150, 300), 60, replace=False)] = False  # and 40 % loss later on
    stamps = np.arange(300)[kept] * PERIOD + rng.integers(-3_000_000, 3_000_000, kept.sum())
    gaps = StreamGaps()
    reports = feed(gaps, stamps)
    assert gaps.lost == 300 - kept.sum() - int(not kept[-1])  # a loss at the very end has no later stamp
    assert sum(r.lost for r in reports) == gaps.lost
    assert abs(gaps.period_ns - PERIOD) < 5_000_000


def test_given_period_and_restarts():
    gaps = StreamGaps(period_ns=PERIOD)
    assert [r.lost for r in feed(gaps, [0, PERIOD, 4 * PERIOD])] == [2]
    feed(gaps, [0, PERIOD])  # a replay started again: a new sequence, nothing counted
    assert gaps.lost == 2
    gaps.reset()
    assert feed(gaps, [10 * PERIOD]) == [] and gaps.lost == 2


def test_silence_counts_only_while_idle():
    logs = []
    watch = InputWatch({"rgb": "/rgb", "depth": "/depth"}, logs.append, {"depth": "remap depth/image"})
    watch.started -= 10.0  # the node has waited 10 s for depth
    watch.tick("rgb")
    # busy since long before: the node became idle just now, so depth has been silent 0 s of idle time
    assert watch.silent(1.0, idle_since=time.monotonic()) == [] and logs == []
    # idle for 5 s: depth is silent, with the advice
    assert watch.silent(1.0, idle_since=time.monotonic() - 5.0) == ["depth"]
    assert len(logs) == 1 and "remap depth/image" in logs[0] and "never received" in logs[0]


def test_activity_busy_and_rate():
    idle = [True]
    activity = Activity(lambda: idle[0])
    assert activity.idle_since() == activity.started and activity.rate_hz() == 0.0
    idle[0] = False
    activity.begin()
    assert activity.idle_since() is None and activity.busy_s() >= 0.0
    for _ in range(3):
        time.sleep(0.02)
        activity.end()
    idle[0] = True
    assert 10.0 < activity.rate_hz() < 60.0
    assert activity.idle_since() >= activity.started and activity.busy_s() == 0.0


def test_period_estimate_equals_numpys_quantile_of_the_window():
    rng = np.random.default_rng(2)
    stamps = np.cumsum(rng.choice([PERIOD, 2 * PERIOD, 3 * PERIOD], 500, p=[0.7, 0.2, 0.1]))
    stamps += rng.integers(-3_000_000, 3_000_000, 500)
    gaps = StreamGaps()
    for i, stamp in enumerate(stamps):
        gaps.add(int(stamp))
        window = np.diff(stamps[: i + 1])[-64:]
        if len(window) >= 8:
            assert abs(gaps.period_ns - np.quantile(window, 0.2)) <= 1  # int() of the same value
        else:
            assert gaps.period_ns is None
