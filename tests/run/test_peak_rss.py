"""The run's own peak memory: a batch runs many sequences in one process, so each run resets the mark."""

import mmap
import sys

import numpy as np
import pytest

from gsslam.run.memory import peak_rss_mb, reset_peak_rss, rss_mb

linux_only = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="clear_refs is Linux's")


@linux_only
def test_reset_forgets_an_earlier_peak():
    assert reset_peak_rss()
    base = peak_rss_mb()
    # 300 MB of anonymous pages, every page touched, unmapped on close: memory the allocator cannot keep
    # resident after it is freed (a numpy block may land in a heap that glibc does not trim)
    block = mmap.mmap(-1, 300 * 2**20)
    view = np.frombuffer(block, dtype=np.uint8)
    view[:] = 1
    del view
    during = rss_mb()
    block.close()
    assert during >= base + 250
    assert peak_rss_mb() >= base + 250  # the mark keeps the block after it is freed ...
    assert reset_peak_rss()
    assert peak_rss_mb() < base + 100  # ... until the next run resets it
    assert peak_rss_mb() >= rss_mb() - 1


def test_peak_is_at_least_the_current_size():
    assert peak_rss_mb() >= rss_mb() - 1 > 0
