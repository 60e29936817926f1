"""The freed heap goes back to the OS at keyframes (the resident size falls), and is reused in between."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from sgs_slam_core.slam.heap import release_free_heap

pytestmark = pytest.mark.slow  # subprocesses and 200 MB of heap: left out of make test-fast


def _rss_mb() -> float:
    return int(Path("/proc/self/statm").read_text().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc_trim")
def test_free_pages_inside_the_heap_go_back():
    blocks = [bytes(2000) for _ in range(100_000)]  # ~200 MB from the heap (below the mmap threshold)
    kept = blocks[::10]  # one in ten stays: the heap cannot shrink from its top
    del blocks
    before = _rss_mb()
    assert release_free_heap()
    after = _rss_mb()
    assert before - after > 50, (before, after)
    assert len(kept) == 10_000


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_freed_frame_buffers_are_reused_without_faulting_their_pages_in_again():
    """With the heap kept, a frame-sized buffer freed and allocated again costs no new page faults.

    In a child process: the setting is process-wide, and the count must start from glibc's defaults.
    """
    code = """
import resource
from sgs_slam_core.slam.heap import keep_freed_heap

def faults(rounds):
    start = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(rounds):
        frame = [bytearray(4 * 2**20) for _ in range(8)]  # a frame's buffers: 8 x 4 MB alive together
        del frame
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - start

faults(2)  # glibc raises its thresholds after the first frees
before = faults(10)
kept = keep_freed_heap()
faults(2)
after = faults(10)
print(kept, before, after)
"""
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    kept, before, after = out.stdout.split()
    assert kept == "True"
    assert int(before) > 10 * 8 * 4 * 2**20 // 4096 // 2, before  # by default most pages fault in every frame
    assert int(after) < int(before) / 100, (before, after)


def test_the_environment_takes_precedence():
    code = "from sgs_slam_core.slam.heap import keep_freed_heap; print(keep_freed_heap())"
    env = dict(os.environ, MALLOC_TOP_PAD_="0")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    assert out.stdout.strip() == "False"
