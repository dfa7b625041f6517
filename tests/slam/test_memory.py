"""What a run keeps per keyframe: packed submaps, keyframe depths shared with them, same results."""

from __future__ import annotations

import numpy as np
import pytest

from gsslam.config import load_config
from gsslam.datasets.synthetic import SyntheticDataset
from gsslam.slam.chains import stored_nbytes
from gsslam.slam.pipeline import Pipeline
from gsslam.types import SubmapEncoding

pytestmark = pytest.mark.slow  # whole pipeline runs

FAST = ["mapper.enabled=false", "loop.enabled=false"]


def _run(n_frames: int, marks: tuple[int, ...]):
    ds = SyntheticDataset(n_frames=n_frames, width=320, height=240, trajectory="orbit", arc_deg=120, seed=3)
    pipe = Pipeline(load_config(None, FAST, mode="rgbd"), ds.intrinsics)
    seen = {}
    for i in range(n_frames):
        pipe.process(ds[i])
        if i + 1 in marks:
            seen[i + 1] = (len(pipe.keyframes), stored_nbytes(pipe.chains, pipe.keyframes))
    pipe.finish()
    return pipe, seen


def test_stored_bytes_per_keyframe_stay_small():
    pipe, seen = _run(48, (16, 48))
    (k0, b0), (k1, b1) = seen[16], seen[48]
    assert k1 - k0 >= 6
    per_kf = (b1 - b0) / (k1 - k0)
    # 320x240 point maps: depth float32 + confidence uint8 per keyframe, the shared one twice:
    # measured 448001 bytes (before packing: whole float32 point maps + confidences + depth copies, 1.74 MB)
    assert per_kf < 0.5e6, per_kf
    for chain in pipe.chains:
        for enc in chain.encodings:
            # packed (RGB-D maps are back-projected depth): z float32 + confidence uint8 = 5/12 of xyz
            assert enc.nbytes <= 5 / 12 * enc.points_cam.nbytes + 64
    for idx, kf in pipe.keyframes.items():
        enc = pipe.chains[kf.chain].encodings[kf.submap]
        assert np.shares_memory(kf.depth, enc.depths), idx


def test_packing_changes_no_pose(monkeypatch):
    packed, _ = _run(30, ())
    monkeypatch.setattr(SubmapEncoding, "pack", lambda self: False)
    whole, _ = _run(30, ())
    assert all(
        e.nbytes == e.points_cam.nbytes + e.confidence.nbytes for c in whole.chains for e in c.encodings
    )
    a, b = packed.frame_poses(), whole.frame_poses()
    assert a.keys() == b.keys() and len(a) == 30
    assert all(np.array_equal(a[i], b[i]) for i in a)  # bit for bit
