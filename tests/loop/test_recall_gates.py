"""The gates that decide loop recall: the view-angle limit of the candidate overlap and the mono inlier
gates of verification (docs/loop_closure.md, "Recall"). Each must keep true loops and refuse false ones."""

from __future__ import annotations

import numpy as np
import pytest

from gsslam.config import LoopConfig
from gsslam.datasets.synthetic import block_room, make_submaps
from gsslam.datasets.synthetic.trajectories import outward_circle, wall_scan, yaw_pose
from gsslam.geometry import invert_T, make_T, so3_exp, so3_log, split_sim3, transform_points
from gsslam.loop import LoopDetector
from gsslam.loop.covisibility import reprojection_overlap
from gsslam.loop.ray_gate import range_inlier_test, ray_inlier_test
from helpers.loop_scenes import DRIFT, gt_relative, run_detector

TARGET = np.array([0.0, 0.0, 4.0])  # a point on the +z wall of the block room


def _wall_views(angle_deg: float):
    """Three submaps (K=6) looking at the same wall patch: 0 straight on, 2 from ``angle_deg`` aside."""
    poses = []
    for k in range(19):
        a = np.radians(angle_deg) if k >= 7 else 0.0
        d = np.array([np.sin(a), 0.0, np.cos(a)])
        side = np.array([np.cos(a), 0.0, -np.sin(a)])
        poses.append(yaw_pose(TARGET - 2.5 * d + 0.03 * (k % 7) * side, a))
    sm = make_submaps(block_room(seed=7), np.stack(poses), mono=False, seed=0)
    det = LoopDetector(LoopConfig(), mode="rgbd")
    for s, (enc, img) in enumerate(zip(sm.encodings, sm.images)):
        det.add_submap(s, enc, img)
    return sm, det


def _overlap(sm, det, max_angle):
    gt = sm.T_world_local_gt
    return reprojection_overlap(det.record(2), gt[2], det.record(0), gt[0], 0.2, max_angle)[0]


def test_view_angle_limit_drops_a_wall_seen_from_60_degrees_aside_keeps_10():
    sm, det = _wall_views(60.0)
    # the same wall patch, depth-consistent: the overlap test alone calls it a loop (measured 0.86)
    assert _overlap(sm, det, 180.0) > 0.5
    # ... but no feature matches across 60 deg: with the limit there is no overlap (measured 0.0)
    assert _overlap(sm, det, 30.0) < 0.05
    sm, det = _wall_views(10.0)
    assert _overlap(sm, det, 30.0) > 0.5  # a revisit from nearly the same direction stays (measured 0.95)


def _correct(sm, loop, trans_tol, rot_tol=1.0, scale_tol=0.03):
    R, t, s = split_sim3(np.linalg.inv(gt_relative(sm, loop.i, loop.m)) @ loop.T_i_m)
    return (
        np.degrees(np.linalg.norm(so3_log(R))) < rot_tol
        and np.linalg.norm(t) < trans_tol
        and abs(s - 1) < scale_tol
    )


@pytest.fixture(scope="module")
def noisy_revisit_mono():
    # depth noise 4 % per pixel (the fixture's is 0.5 %): what a hand-held mono point map has
    return make_submaps(
        block_room(seed=1), outward_circle(61, 1.2), mono=True, seed=3, depth_noise=0.04, **DRIFT
    )


# measured (all 3 revisit candidates verified by both): range at most 1.57 deg / 6.4 % of the depth / 3.9 % in
# scale, ray 0.22 deg / 1.7 % / 0.8 %; the "median" gate at the same 4 % verifies 1 of the 3 (2.0 deg / 8.7 %)
@pytest.mark.parametrize(
    "gate, rot_tol, trans_rel, scale_tol", [("range", 2.0, 0.08, 0.05), ("ray", 0.5, 0.03, 0.02)]
)
def test_mono_gates_verify_a_true_loop_with_noisy_depth(
    noisy_revisit_mono, gate, rot_tol, trans_rel, scale_tol
):
    sm = noisy_revisit_mono
    cfg = LoopConfig(mono_inlier_gate=gate, inlier_threshold_rel=0.04, ray_depth_rel=0.08)
    det, _, loops = run_detector(sm, "mono", cfg)
    assert len(loops) == det.stats.candidates == 3  # every candidate of the revisit verified
    assert all(lp.i >= 8 and lp.m <= 1 for lp in loops.values())
    for lp in loops.values():
        tol = trans_rel * det.record(lp.i).median_depth
        assert _correct(sm, lp, trans_tol=tol, rot_tol=rot_tol, scale_tol=scale_tol), (lp.i, lp.m)


@pytest.fixture(scope="module")
def mono_corridor():
    room = block_room(half_extent=(11.0, 1.5, 3.0), seed=4)
    return make_submaps(room, wall_scan(61, 18.0, 2.5, 3.0), mono=True, seed=5, **DRIFT)


@pytest.mark.parametrize("gate", ["median", "range", "ray"])
def test_mono_gates_refuse_lookalikes_when_every_nearby_submap_is_a_candidate(mono_corridor, gate):
    """No revisit; with the overlap/score tests off every nearby submap reaches RANSAC: whatever a
    gate verifies must be geometrically right (a neighbour's true overlap), never a look-alike."""
    cfg = LoopConfig(
        min_overlap=-1.0, min_score=-1.0, max_candidates=10, skip_recent=1, mono_inlier_gate=gate,
        max_view_angle_deg=180.0,
    )  # fmt: skip
    det, _, loops = run_detector(mono_corridor, "mono", cfg)
    assert det.stats.candidates > 0
    for lp in loops.values():
        assert _correct(mono_corridor, lp, trans_tol=0.05 * det.record(lp.i).median_depth), (gate, lp.i, lp.m)


@pytest.mark.parametrize("make_test", ["range", "ray"])
def test_inlier_tests_follow_depth_noise_and_refuse_a_wrong_transform(make_test):
    """Matches with 3 % depth noise along the ray pass under the true Sim(3) at any submap scale; under a
    transform 5 deg / 10 % of the depth off, almost none do."""
    rng = np.random.default_rng(0)
    n = 400
    rays = np.column_stack([rng.uniform(-0.5, 0.5, (n, 2)), np.ones(n)])
    z = rng.uniform(1.0, 4.0, n)
    T_lc = np.stack([np.eye(4), make_T(so3_exp(np.array([0.0, 0.1, 0.0])), np.array([0.2, 0.0, 0.0]))])
    view = rng.integers(0, 2, n)
    Xc = rays * (z * (1.0 + 0.03 * rng.standard_normal(n)))[:, None]  # noisy along the ray
    X_i = np.einsum("nij,nj->ni", T_lc[view, :3, :3], Xc) + T_lc[view, :3, 3]
    for scale in (0.1, 1.0, 10.0):
        T = make_T(so3_exp(np.array([0.3, -0.2, 0.1])), np.array([0.5, 0.1, -0.3]), 1.7)
        X_true = rays * z[:, None]
        X_m = transform_points(
            invert_T(T), np.einsum("nij,nj->ni", T_lc[view, :3, :3], X_true) + T_lc[view, :3, 3]
        )
        S = make_T(np.eye(3), np.zeros(3), scale)  # the same scene in other units
        T_s = S @ T @ invert_T(S)
        T_lc_s = T_lc.copy()
        T_lc_s[:, :3, 3] *= scale
        args = (scale * X_i, scale * X_m, view, T_lc_s)
        test = range_inlier_test(*args, 0.08) if make_test == "range" else ray_inlier_test(*args, 1.0, 0.08)
        assert test(T_s).mean() > 0.9  # measured 0.99 (range), 0.99 (ray)
        off = T_s @ make_T(so3_exp(np.array([0.0, np.radians(5.0), 0.0])), np.array([0.0, 0.0, 0.25 * scale]))
        assert test(off).mean() < 0.2
