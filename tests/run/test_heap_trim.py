"""Free heap pages handed back to the system (glibc malloc_trim), only when the run's submaps grew."""

import sys

import pytest

from gsslam.run import memory
from gsslam.run.memory import HeapTrimmer, rss_mb, trim_heap

linux_only = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc_trim")


@linux_only
def test_trim_returns_freed_heap_pages_that_free_keeps():
    # 2 KB blocks come from malloc's heap (not mmap): freeing most of them leaves free chunks between live
    # ones, which glibc keeps resident; one block in 16 stays alive so the heap cannot simply shrink
    blocks = [bytes(2000) + bytes([i % 251]) for i in range(100_000)]  # ~200 MB, every page touched
    keep = blocks[::16]
    del blocks
    before = rss_mb()
    assert trim_heap()
    after = rss_mb()
    assert before - after > 100, (before, after)  # ~190 MB were free heap
    assert len(keep) == 6250 and keep[5][-1] == 80 % 251  # the live blocks are untouched


def test_trimmer_trims_when_the_count_grows_and_only_if_enabled(monkeypatch):
    calls = []
    monkeypatch.setattr(memory, "trim_heap", lambda: calls.append(1) or True)
    t = HeapTrimmer(True, count=2)
    for n in (2, 2, 3, 3, 5, 5):
        t.after(n)
    assert t.trims == len(calls) == 2
    t.now()
    assert t.trims == 3
    off = HeapTrimmer(False)
    off.after(4)
    off.now()
    assert off.trims == 0 and len(calls) == 3
