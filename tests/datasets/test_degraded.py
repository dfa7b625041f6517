"""Faster playback (stride), synthesized motion blur along the ground-truth motion and exposure swings."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from gsslam.datasets.base import open_dataset
from gsslam.datasets.degraded import Degradation, DegradationError, exposure_ends, motion_blur
from gsslam.datasets.playback import PlaybackError, interpolate_trajectory, playback_plan
from gsslam.geometry import invert_T, make_T
from gsslam.types import CameraIntrinsics

K = CameraIntrinsics(500.0, 500.0, 79.5, 59.5, 160, 120)
DEG = {"shutter": 0.5, "exposure_amp": 0.3, "exposure_period": 40}


def test_plan_with_stride():
    assert playback_plan(7, "fbf", stride=3).tolist() == [0, 3, 6, 3, 0, 3, 6]
    assert playback_plan(8, "f", stride=3).tolist() == [0, 3, 6]
    with pytest.raises(PlaybackError):
        playback_plan(4, "f", stride=4)  # one frame left
    with pytest.raises(PlaybackError):
        playback_plan(4, "f", stride=0)


def test_degradation_settings_are_checked():
    assert Degradation.from_dict(None) is None
    with pytest.raises(DegradationError):
        Degradation.from_dict({"shuter": 0.5})
    with pytest.raises(DegradationError):
        Degradation(shutter=-0.1)
    d = Degradation(exposure_amp=0.3, exposure_period=40)
    g = np.array([d.gain(k) for k in range(80)])
    assert g.min() >= np.exp(-0.3) - 1e-9 and g.max() <= np.exp(0.3) + 1e-9 and g.max() > 1.3
    assert Degradation().gain(7) == 1.0


def _stripes() -> np.ndarray:  # [120, 160, 3]: vertical stripes in the left half, horizontal in the right
    img = np.zeros((120, 160, 3), np.float32)
    img[:, :80] = ((np.arange(80) // 10) % 2)[None, :, None]
    img[:, 80:] = ((np.arange(120) // 10) % 2)[:, None, None]
    return img


def test_blur_is_along_the_motion_and_as_long_as_it():
    img, depth = _stripes(), np.full((120, 160), 2.0, np.float32)
    # the camera moves +4 cm along x per frame; the half-frame exposure spans +-1 cm: +-2.5 px at 2 m
    T_prev, T_k, T_next = make_T(np.eye(3), [-0.04, 0, 0]), np.eye(4), make_T(np.eye(3), [0.04, 0, 0])
    ends = exposure_ends(Degradation(shutter=0.5), T_prev, T_k, T_next)
    assert np.allclose(ends[1][:3, 3], [-0.01, 0, 0])
    out = motion_blur(img, depth, K, ends, samples=11)
    # horizontal stripes (motion along them) stay sharp, vertical ones are box-filtered over 5 px
    assert np.allclose(out[20:100, 90:150], img[20:100, 90:150], atol=1e-5)
    want = cv2.blur(img, (5, 1), borderType=cv2.BORDER_REPLICATE)
    err = np.abs(out[20:100, 10:70] - want[20:100, 10:70])
    assert err.max() < 0.15 and err.mean() < 0.03  # measured 0.10 / 0.011 (11 samples vs a 5-tap box)
    # no motion, no blur; unknown neighbours count as no motion
    still = motion_blur(img, depth, K, exposure_ends(Degradation(shutter=0.5), None, T_k, None))
    assert np.allclose(still, img, atol=1e-5)


@pytest.fixture(scope="module")
def played(bundled_tum):
    kw = dict(base="tum", pattern="fbf", stride=3, pause_every=9, pause_len=2, degrade=DEG)
    return open_dataset("tum", bundled_tum), open_dataset("playback", bundled_tum, **kw), kw


def test_degraded_playback_is_deterministic(played, bundled_tum):
    base, ds, kw = played
    again = open_dataset("playback", bundled_tum, **kw)
    plan = playback_plan(len(base), "fbf", pause_every=9, pause_len=2, stride=3)
    assert len(ds) == len(plan) and ds.name.endswith("_s3")
    for k in (4, 23):
        assert ds.source_index(k) == plan[k]
        assert np.array_equal(ds[k].image, again[k].image)
        assert not np.allclose(ds[k].image, base[int(plan[k])].image, atol=0.02)  # it is degraded
    # a frame inside a pause (the same source before and after it) has no blur: only its exposure gain
    k = 9  # plan[8] == plan[9] == plan[10]
    assert plan[8] == plan[9] == plan[10]
    g = Degradation.from_dict(DEG).gain(k)
    want = np.clip(base[int(plan[k])].image * np.float32(g), 0, 1)
    assert np.allclose(ds[k].image, want, atol=1e-5)


def _flow_error(a, b, T_b_a) -> float:
    """Median |predicted - DIS flow| (px) from frame a to b over a's textured pixels with depth, the
    prediction being a's depth moved by ``T_b_a``."""
    ga, gb = (cv2.cvtColor((f.image * 255).astype(np.uint8), cv2.COLOR_RGB2GRAY) for f in (a, b))
    flow = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM).calc(ga, gb, None)
    tex = np.hypot(cv2.Sobel(ga, cv2.CV_32F, 1, 0), cv2.Sobel(ga, cv2.CV_32F, 0, 1)) > 40
    v, u = np.mgrid[0 : a.depth.shape[0] : 4, 0 : a.depth.shape[1] : 4]
    z = a.depth[v, u]
    m = np.isfinite(z) & (z > 0) & tex[v, u]
    i = a.intrinsics
    X = np.stack([(u[m] - i.cx) / i.fx * z[m], (v[m] - i.cy) / i.fy * z[m], z[m]], 1) @ T_b_a[:3, :3].T
    X += T_b_a[:3, 3]
    pu, pv = i.fx * X[:, 0] / X[:, 2] + i.cx - u[m], i.fy * X[:, 1] / X[:, 2] + i.cy - v[m]
    return float(np.median(np.hypot(pu - flow[v[m], u[m], 0], pv - flow[v[m], u[m], 1])))


def test_ground_truth_follows_the_played_frames(played):
    """The ground truth of played frames k, k+1 (3 source frames apart) predicts the flow between
    their images: frame k's depth moved by it lands where dense flow says (the base images, undegraded:
    this checks the plan and the ground truth, not the blur)."""
    base, ds, _ = played
    gt_base = base.ground_truth()
    errs, wrong = [], []
    for k in (4, 13, 26):  # source frames 12->15, 36->39, 48->45 (the first ones have no ground truth)
        a, b = base[ds.source_index(k)], base[ds.source_index(k + 1)]
        Ta, Tb, T2 = (ds[j].T_world_cam_gt for j in (k, k + 1, k + 2))
        ok, want = interpolate_trajectory(gt_base, np.array([a.timestamp]), 0.1)
        assert ok[0] and np.allclose(Ta, want[0])
        errs.append(_flow_error(a, b, invert_T(Tb) @ Ta))
        wrong += [_flow_error(a, b, np.eye(4)), _flow_error(a, b, invert_T(T2) @ Ta)]
    assert max(errs) < 3.5  # measured 2.0-2.6 px
    assert min(wrong) > 2.0 * max(errs)  # no motion or the next frame's pose: measured 6.6-33 px
