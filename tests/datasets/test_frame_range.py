"""FrameRange: a run that starts part-way into a real sequence sees exactly those frames."""

from __future__ import annotations

import numpy as np
import pytest

from gsslam.datasets import DatasetError, open_dataset
from gsslam.datasets.frame_range import FrameRange


def test_range_is_the_slice_of_the_sequence(bundled_tum):
    ds = open_dataset("tum", bundled_tum)
    part = FrameRange(ds, 20, 35)
    assert len(part) == 15
    assert part.timestamps() == ds.timestamps()[20:35]
    assert part[0].timestamp == ds[20].timestamp and part[0].index == 0 and part[-1].index == 14
    assert np.array_equal(part[-1].image, ds[34].image)
    assert part.intrinsics == ds.intrinsics and part.has_depth == ds.has_depth
    assert part.ground_truth() is not None and len(part.ground_truth()) == len(ds.ground_truth())
    with pytest.raises(IndexError):
        part[15]


@pytest.mark.parametrize("start, stop", [(-1, None), (60, None), (10, 10), (10, 61)])
def test_bad_ranges_are_refused_with_the_length(bundled_tum, start, stop):
    ds = open_dataset("tum", bundled_tum)
    with pytest.raises(DatasetError, match=str(len(ds))):
        FrameRange(ds, start, stop)
