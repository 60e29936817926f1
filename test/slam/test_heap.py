"""The freed heap goes back to the OS: the resident size falls once live data is released."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

from sgs_slam_core.slam.heap import release_free_heap


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
