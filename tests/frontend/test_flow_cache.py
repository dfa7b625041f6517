"""The flow cache: a repeated image pair is computed once, results are unchanged, entries die with images."""

from __future__ import annotations

import gc

import numpy as np

from gsslam.frontend.flow import DISFlow
from helpers.tum import load_tum


def test_cached_flow_equals_fresh_flow_and_is_released(bundled_tum):
    imgs = [f.image.copy() for f in load_tum(bundled_tum, [0, 4])]
    flow = DISFlow("ultrafast", 320, 0)
    fresh = DISFlow("ultrafast", 320, 0, cache=False)
    a = flow(imgs[0], imgs[1])
    a[:] = 0.0  # callers get a copy: editing it leaves the cache intact
    b = flow(imgs[0], imgs[1])
    assert flow.cache.hits == 1 and flow.cache.misses == 1
    assert np.array_equal(b, fresh(imgs[0], imgs[1]))
    assert np.abs(b).max() > 0.5  # a real flow, not the zeroed copy
    flow(imgs[1], imgs[0])  # the other direction is another pair
    assert flow.cache.misses == 2 and len(flow.cache) == 2
    flow(imgs[0].copy(), imgs[1])  # equal content, other array: no hit (identity keys)
    assert flow.cache.hits == 1
    flow(imgs[0], imgs[1], init=b)  # a flow with an initial guess is never cached
    assert flow.cache.hits == 1
    del imgs[0]
    gc.collect()
    assert len(flow.cache) == 0
