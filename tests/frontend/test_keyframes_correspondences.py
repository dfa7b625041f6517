"""Keyframe rule and flow-correspondence sampling."""

from __future__ import annotations

import numpy as np
import pytest

from gsslam.config import KeyframeConfig
from gsslam.frontend.correspondences import CorrespondenceError, correspondences_from_flow
from gsslam.frontend.keyframes import KeyframeError, KeyframeSelector, median_flow_magnitude
from gsslam.types import CameraIntrinsics, Frame


def _flow(mag: float, H: int = 30, W: int = 40) -> np.ndarray:
    f = np.zeros((H, W, 2), np.float32)
    f[..., 0] = mag * 0.6
    f[..., 1] = mag * 0.8
    return f


def test_keyframe_by_flow_magnitude_and_gap():
    sel = KeyframeSelector(KeyframeConfig(min_flow_px=10.0, max_gap=5))
    assert not sel.is_keyframe(_flow(9.0), 1)
    assert sel.is_keyframe(_flow(10.5), 1)
    assert sel.is_keyframe(_flow(0.0), 5)  # gap rule
    assert not sel.is_keyframe(_flow(50.0), 0)  # the keyframe itself
    nan = np.full((30, 40, 2), np.nan, np.float32)
    assert not sel.is_keyframe(nan, 2) and sel.is_keyframe(nan, 5)
    # the median ignores a minority of wild pixels
    f = _flow(2.0)
    f[:5] = 100.0
    assert median_flow_magnitude(f) == pytest.approx(2.0, rel=1e-5)
    valid = np.zeros((30, 40), bool)
    valid[:5] = True
    assert sel.is_keyframe(f, 1, valid=valid)
    with pytest.raises(KeyframeError):
        KeyframeSelector(KeyframeConfig(max_gap=0))


def _frame(i: int, H: int = 60, W: int = 80) -> Frame:
    intr = CameraIntrinsics(100.0, 100.0, W / 2, H / 2, W, H)
    return Frame(i, float(i), np.zeros((H, W, 3), np.float32), intr)


def test_correspondences_follow_flow_and_depth():
    src, tgt = _frame(3), _frame(7)
    H, W = 60, 80
    flow = np.zeros((H, W, 2), np.float32)
    flow[..., 0], flow[..., 1] = 4.0, -2.0
    valid = np.ones((H, W), bool)
    valid[:, :20] = False  # must never be sampled
    depth = np.full((H // 2, W // 2), 2.0, np.float32)  # lower resolution depth is accepted
    depth[:, 30:] = np.nan
    rng = np.random.default_rng(0)
    c = correspondences_from_flow(src, tgt, flow, valid, depth, 500, rng)
    assert len(c) == 500 and (c.src_index, c.tgt_index) == (3, 7)
    assert np.allclose(c.uv_tgt - c.uv_src, [4.0, -2.0])
    assert (c.uv_src[:, 0] >= 20).all()
    assert (c.uv_tgt[:, 1] >= 0).all() and (c.uv_tgt[:, 0] <= W - 1).all()
    right = c.uv_src[:, 0] >= 60
    assert np.isnan(c.depth_src[right]).all() and np.allclose(c.depth_src[~right], 2.0)
    # stratified: samples spread over the valid area, not clumped
    hist = np.histogram(c.uv_src[:, 0], bins=6, range=(20, 80))[0]
    assert hist.min() > 0.5 * hist.mean()
    assert np.all((c.weight > 0) & (c.weight <= 1))


def test_correspondences_weights_and_errors():
    src, tgt = _frame(0), _frame(1)
    flow = np.zeros((60, 80, 2), np.float32)
    fb = np.zeros((60, 80), np.float32)
    fb[:, 40:] = 4.0
    c = correspondences_from_flow(
        src, tgt, flow, np.ones((60, 80), bool), None, 10000, np.random.default_rng(1), fb_error=fb
    )
    assert len(c) == 60 * 80 and np.isnan(c.depth_src).all()
    assert np.allclose(c.weight[c.uv_src[:, 0] < 40], 1.0) and (c.weight[c.uv_src[:, 0] >= 40] < 0.05).all()
    with pytest.raises(CorrespondenceError):
        correspondences_from_flow(
            src, tgt, flow[:10], np.ones((60, 80), bool), None, 10, np.random.default_rng()
        )
