"""Frame prefetching: same frames in the same order, errors surface, the thread always stops."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from gsslam.datasets.base import open_dataset
from gsslam.datasets.prefetch import FramePrefetcher, PrefetchedDataset


def _threads() -> int:
    return sum(t.name == "gsslam-prefetch" and t.is_alive() for t in threading.enumerate())


def test_prefetched_frames_equal_direct_reads(bundled_tum):
    ds = open_dataset("tum", bundled_tum)
    with PrefetchedDataset(ds, depth=2, stop=8) as pre:
        assert len(pre) == len(ds) and pre.intrinsics == ds.intrinsics
        for i in [0, 1, 2, 3, 1, 4, 6, 7, 8]:  # in order, an earlier frame, a skip, past ``stop``
            a, b = pre[i], ds[i]
            assert a.index == b.index == i and a.timestamp == b.timestamp
            assert np.array_equal(a.image, b.image)
            assert np.array_equal(a.depth, b.depth, equal_nan=True)
        assert pre.ground_truth() is not None
    assert _threads() == 0


class _Failing:
    def __init__(self, n: int, bad: int) -> None:
        self.n, self.bad = n, bad

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, i: int) -> int:
        if i == self.bad:
            raise ValueError(f"cannot decode frame {i}")
        return i


def test_reader_error_is_raised_at_its_frame_and_break_stops_thread():
    got = []
    with pytest.raises(ValueError, match="frame 3"):
        for x in FramePrefetcher(_Failing(10, 3), depth=2):
            got.append(x)
    assert got == [0, 1, 2]
    pre = FramePrefetcher(_Failing(1000, -1), depth=2)
    for x in pre:
        if x == 5:
            break
    pre.close()
    assert not pre._thread.is_alive()
    assert _threads() == 0
