"""Unit tests of the stages: RANSAC 3D-3D, reprojection overlap, record size, appearance."""

from __future__ import annotations

import numpy as np
import pytest

from gsslam.geometry import invert_T, make_T, so3_exp, split_sim3, transform_points
from gsslam.loop.appearance import appearance_overlap, global_descriptor
from gsslam.loop.covisibility import DEPTH_SMALL_MAX_SIDE, reprojection_overlap
from gsslam.loop.verification import ransac_transform


@pytest.mark.parametrize("with_scale", [False, True])
def test_ransac_recovers_transform_among_outliers(with_scale):
    rng = np.random.default_rng(1)
    T = make_T(so3_exp(rng.normal(size=3)), rng.normal(size=3), 1.7 if with_scale else 1.0)
    X_m = rng.uniform(-2, 2, size=(300, 3))
    X_i = transform_points(T, X_m) + 0.005 * rng.normal(size=(300, 3))
    out = rng.random(300) < 0.6  # 60 % wrong matches
    X_i[out] = rng.uniform(-4, 4, size=(out.sum(), 3))
    T_est, inl = ransac_transform(X_i, X_m, 0.03, with_scale, 300, rng)
    assert T_est is not None
    assert inl[~out].mean() > 0.95 and inl[out].mean() < 0.02
    R, t, s = split_sim3(invert_T(T) @ T_est)
    assert np.abs(R - np.eye(3)).max() < 5e-3 and np.linalg.norm(t) < 1e-2 and abs(s - 1) < 5e-3


def test_ransac_finds_no_model_in_unrelated_points():
    rng = np.random.default_rng(2)
    X_i, X_m = rng.uniform(-2, 2, size=(2, 200, 3))
    _, inl = ransac_transform(X_i, X_m, 0.05, False, 300, rng)
    assert inl.sum() < 10


def test_reprojection_overlap_of_a_submap_with_itself_and_moved_away(revisit_rgbd):
    _, det, est, _ = revisit_rgbd
    rec = det.record(3)
    ratio, counts = reprojection_overlap(rec, est[3], rec, est[3], det.cfg.depth_tolerance_rel)
    assert ratio > 0.95
    assert np.all(np.diag(counts) >= counts.max(axis=1) * 0.999)  # a view sees its own points most
    far = make_T(np.eye(3), [50.0, 0.0, 0.0]) @ est[3]
    assert reprojection_overlap(rec, est[3], rec, far, det.cfg.depth_tolerance_rel)[0] == 0.0
    turned = est[3] @ make_T(so3_exp(np.array([0.0, np.pi, 0.0])), np.zeros(3))
    assert reprojection_overlap(rec, est[3], rec, turned, det.cfg.depth_tolerance_rel)[0] < 0.1


def test_records_are_bounded(revisit_rgbd):
    _, det, _, _ = revisit_rgbd
    for k in range(len(det)):
        rec = det.record(k)
        assert len(rec.points_local) <= det.cfg.points_per_submap
        assert max(rec.depth_small.shape[1:]) <= DEPTH_SMALL_MAX_SIDE
        assert all(len(f.descriptors) <= det.cfg.orb_features for f in rec.features)


def test_appearance_same_view_high_unrelated_low(revisit_rgbd):
    sm = revisit_rgbd[0]
    a = np.stack([global_descriptor(im) for im in sm.images[0]])
    b = np.stack([global_descriptor(im) for im in sm.images[4]])  # opposite side of the room
    assert np.allclose(np.diag(appearance_overlap(a, a)), 1.0, atol=1e-5)
    assert appearance_overlap(a, b).max() < 0.6
