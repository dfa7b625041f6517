"""The next submap's encoder gets the shared frame's depth together with the confidence that the
submap which made that depth gave it (the mono BA weights its depth prior by it)."""

from __future__ import annotations

import numpy as np
import pytest

from gsslam.config import load_config
from gsslam.datasets.synthetic import SyntheticDataset
from gsslam.slam.chains import keyframe_confidence
from gsslam.slam.pipeline import Pipeline

pytestmark = pytest.mark.slow  # a whole (short) mono pipeline run


def test_shared_depth_comes_with_its_submaps_confidence():
    ds = SyntheticDataset(n_frames=30, width=320, height=240, trajectory="orbit", arc_deg=90, seed=3)
    cfg = load_config(None, ["mapper.enabled=false", "loop.enabled=false"], mode="mono")
    pipe = Pipeline(cfg, ds.intrinsics)
    calls = []
    encode = pipe.encoder.encode

    def spy(frames, shared_depth=None, shared_confidence=None, **kw):
        if shared_depth is not None:
            kf = pipe.keyframes[frames[0].index]
            made = pipe.chains[kf.chain].encodings[kf.submap]
            calls.append(
                (shared_confidence, made.confidence[kf.position], keyframe_confidence(pipe.chains, kf))
            )
        return encode(frames, shared_depth=shared_depth, shared_confidence=shared_confidence, **kw)

    pipe.encoder.encode = spy
    for i in range(len(ds)):
        pipe.process(ds[i])
    pipe.finish()
    assert len(calls) >= 2  # every submap after the first of the chain
    for given, made, looked_up in calls:
        assert given is not None and given.shape == made.shape
        assert np.array_equal(given, made) and np.array_equal(looked_up, made)
        assert 0.0 <= given.min() and given.max() <= 1.0 and (given > 0).any()
