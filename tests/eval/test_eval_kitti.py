"""KITTI t_rel / r_rel against a literal loop over the devkit's definition and known drifts."""

from __future__ import annotations

import numpy as np
import pytest

from gsslam.eval.kitti import KittiMetricError, kitti_relative_errors, path_distances
from gsslam.geometry import make_T


def _devkit_loop(gt, est, lengths=(100, 200, 300, 400, 500, 600, 700, 800), step=10):
    """evaluate_odometry.cpp's calcSequenceErrors, one sub-sequence at a time (no vectorisation)."""
    dist = [0.0]
    for k in range(1, len(gt)):
        dist.append(dist[-1] + float(np.linalg.norm(gt[k, :3, 3] - gt[k - 1, :3, 3])))
    t_errs, r_errs = [], []
    for first in range(0, len(gt), step):
        for L in lengths:
            last = next((k for k in range(first, len(gt)) if dist[k] > dist[first] + L), -1)
            if last == -1:
                continue
            d_gt = np.linalg.inv(gt[first]) @ gt[last]
            d_est = np.linalg.inv(est[first]) @ est[last]
            E = np.linalg.inv(d_est) @ d_gt
            d = 0.5 * (E[0, 0] + E[1, 1] + E[2, 2] - 1.0)
            r_errs.append(np.arccos(max(min(d, 1.0), -1.0)) / L)
            t_errs.append(np.linalg.norm(E[:3, 3]) / L)
    return 100 * np.mean(t_errs), 100 * np.degrees(np.mean(r_errs)), len(t_errs)


def _rot_y(a):  # [N] -> [N, 3, 3] rotations about y (KITTI's vertical axis)
    c, s = np.cos(a), np.sin(a)
    R = np.zeros((len(a), 3, 3))
    R[:, 0, 0], R[:, 0, 2], R[:, 1, 1], R[:, 2, 0], R[:, 2, 2] = c, s, 1.0, -s, c
    return R


def _drifted(gt, scale_drift=0.0, yaw_deg_per_100m=0.0):
    """Translations scaled by 1 + scale_drift; a yaw about the world vertical growing with distance."""
    est = gt.copy()
    est[:, :3, 3] *= 1.0 + scale_drift
    a = np.radians(yaw_deg_per_100m) * path_distances(gt) / 100.0
    R = _rot_y(a)
    est[:, :3, :3] = R @ est[:, :3, :3]
    est[:, :3, 3] = np.einsum("nij,nj->ni", R, est[:, :3, 3])
    return est


def _kitti_gt(shared_data):
    from gsslam.datasets.kitti import read_kitti_poses

    return read_kitti_poses(shared_data / "kitti_odometry" / "poses" / "06.txt")


def test_shared_kitti_06_scale_drift_matches_devkit(shared_data):
    gt = _kitti_gt(shared_data)  # 1101 poses, ~1.2 km
    est = _drifted(gt, scale_drift=0.02)
    res = kitti_relative_errors(gt, est)
    t_ref, r_ref, n_ref = _devkit_loop(gt, est)
    assert res.segments == n_ref > 300
    assert res.t_rel_pct == pytest.approx(t_ref, rel=1e-9)
    assert res.r_rel_deg_per_100m == pytest.approx(r_ref, abs=1e-6)
    # a 2 % scale error gives t_err = 0.02 |chord| / L: at most 2 %; 06 is a loop, so less (1.19 %)
    assert 1.1 < res.t_rel_pct <= 2.0 + 1e-9
    assert res.r_rel_deg_per_100m < 1e-5  # rotations are exact


def test_shared_kitti_06_yaw_drift_matches_devkit(shared_data):
    gt = _kitti_gt(shared_data)
    est = _drifted(gt, yaw_deg_per_100m=0.5)
    res = kitti_relative_errors(gt, est)
    t_ref, r_ref, _ = _devkit_loop(gt, est)
    assert res.t_rel_pct == pytest.approx(t_ref, rel=1e-9)
    assert res.r_rel_deg_per_100m == pytest.approx(r_ref, rel=1e-9)
    # the drift accumulated over a sub-sequence is 0.5 deg per 100 m of (slightly more than L) path
    assert 0.5 <= res.r_rel_deg_per_100m < 0.52
    assert set(res.per_length) == {100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0}


def test_exact_estimate_and_rigid_invariance():
    rng = np.random.default_rng(0)
    n = 600  # a 1.2 km wavy path, 2 m per frame
    yaw = np.cumsum(rng.normal(0, 0.02, n))
    pos = np.cumsum(np.stack([np.sin(yaw), np.zeros(n), np.cos(yaw)], 1) * 2.0, axis=0)
    gt = np.stack([make_T(_rot_y(yaw[k : k + 1])[0], pos[k]) for k in range(n)])
    assert kitti_relative_errors(gt, gt).t_rel_pct == pytest.approx(0.0, abs=1e-9)
    T = make_T(_rot_y(np.array([0.7]))[0], np.array([5.0, -2.0, 30.0]))
    est = _drifted(gt, scale_drift=0.01)
    moved = T @ est  # a rigid change of the estimate's world frame changes no relative pose
    a, b = kitti_relative_errors(gt, est), kitti_relative_errors(gt, moved)
    assert a.t_rel_pct == pytest.approx(b.t_rel_pct, rel=1e-9)
    assert a.r_rel_deg_per_100m == pytest.approx(b.r_rel_deg_per_100m, abs=1e-6)  # acos: ~1e-8 noise at 0


def test_too_short_and_bad_input():
    gt = np.tile(np.eye(4), (20, 1, 1))
    gt[:, 2, 3] = np.arange(20.0)  # 19 m: no 100 m sub-sequence
    res = kitti_relative_errors(gt, gt)
    assert res.t_rel_pct is None and res.segments == 0
    assert kitti_relative_errors(gt, gt, lengths=(5.0,), step=1).segments == 14  # j = i + 6 <= 19
    with pytest.raises(KittiMetricError):
        kitti_relative_errors(gt, gt[:10])
    with pytest.raises(KittiMetricError):
        kitti_relative_errors(gt, gt, step=0)
