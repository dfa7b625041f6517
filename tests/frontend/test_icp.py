"""Dense point-to-plane ICP on exact synthetic depth, and its refusal cases."""

from __future__ import annotations

import numpy as np
import pytest

from gsslam.datasets.synthetic import SyntheticDataset
from gsslam.frontend.icp import icp_point_to_plane
from gsslam.geometry import invert_T, make_T, so3_exp, so3_log


@pytest.fixture(scope="module")
def frames():
    ds = SyntheticDataset(n_frames=12, width=160, height=120, trajectory="orbit", seed=0)
    return ds, ds[0], ds[4]


def _err(T, G):
    E = invert_T(G) @ T
    return np.linalg.norm(E[:3, 3]), np.degrees(np.linalg.norm(so3_log(E[:3, :3])))


def test_icp_recovers_the_motion_from_a_perturbed_start(frames):
    ds, a, b = frames
    G = invert_T(b.T_world_cam_gt) @ a.T_world_cam_gt  # T_b_a: source a -> target b
    start = make_T(so3_exp(np.array([0.02, -0.015, 0.01])), np.array([0.02, -0.01, 0.015])) @ G
    res = icp_point_to_plane(a.depth, b.depth, ds.intrinsics, start, strides=(4, 2, 1))
    assert res.ok, res.reason
    dt, dr = _err(res.T_tgt_src, G)
    dt0, dr0 = _err(start, G)
    assert dt0 > 0.02 and dr0 > 1.0
    assert dt < 2e-3 and dr < 0.1  # exact depth: sub-millimetre in practice
    assert res.inliers > 1000 and res.rmse_m < 0.005


def test_icp_refuses_a_plane(frames):
    ds, a, _ = frames
    plane = np.full_like(a.depth, 2.0)  # a wall seen head-on: translation along it is unobservable
    res = icp_point_to_plane(plane, plane, ds.intrinsics, np.eye(4), strides=(4, 2))
    assert not res.ok and res.reason == "ill_conditioned"
    assert np.allclose(res.T_tgt_src, np.eye(4))


def test_icp_refuses_missing_depth(frames):
    ds, a, b = frames
    empty = np.full_like(a.depth, np.nan)
    res = icp_point_to_plane(a.depth, empty, ds.intrinsics, np.eye(4))
    assert not res.ok and res.reason == "few_points"


def _rot(v_deg):
    return make_T(so3_exp(np.radians(np.asarray(v_deg, float))), np.zeros(3))


def test_colour_depth_check_flags_a_wrong_colour_focal_length():
    from gsslam.frontend.rgbd_encoder import ColourDepthCheck

    rng = np.random.default_rng(0)
    for factor, expect in ((0.9, True), (1.03, False), (1.0, False), (1.15, True)):
        check = ColourDepthCheck(0.96, 1.08)
        for k in range(12):
            w = rng.normal(size=3) * 2.0  # a few degrees per keyframe pair
            check.add(_rot(factor * w + rng.normal(size=3) * 0.05), _rot(w))
            if k < 7:
                assert not check.mismatch  # needs 8 pairs
        assert np.isclose(check.ratio, factor, atol=0.02) and check.mismatch == expect
        assert check.latched_at == (8 if expect else 0)  # the pair count at the latch (metrics.json)
    check = ColourDepthCheck(0.96, 1.08)
    for _ in range(20):
        check.add(_rot([0.0, 0.2, 0.0]), _rot([0.0, 0.3, 0.0]))  # below 0.5 deg: no evidence
    assert check.pairs == 0 and not check.mismatch
