"""Several two-view hypotheses, chosen by their cost over all tracks, do not follow the random sample.

OpenCV's RANSAC draws its minimal samples by index from a fixed seed, so the order of the matches is
its sample: on a synthetic orbit pair (DIS flow, exact ground truth) the essential rotation lands
0.35-2.5 deg from the truth depending on the order. ``two_view_hypotheses`` makes several orders and
``track_cost`` (Cauchy, every track at its best depth) picks among them. docs/results.md, "Mono
two-view hypotheses, session 9".
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from gsslam.config import load_config
from gsslam.frontend.flow import make_flow_estimator
from gsslam.frontend.mono_encoder import MonoEncoder
from gsslam.frontend.mono_init import rotation_deg, track_cost, track_observations, two_view_hypotheses
from gsslam.frontend.pose_estimation import random_flow_matches
from gsslam.frontend.two_view import two_view_pose
from gsslam.geometry import invert_T, so3_exp, so3_log
from helpers.orbit_pair import orbit_dataset, orbit_flow_pair


@pytest.fixture(scope="module")
def orbit():
    return orbit_dataset()


@pytest.fixture(scope="module")
def pair(orbit):
    return orbit_flow_pair(orbit, 0, 8)


def test_track_cost_is_lowest_at_the_true_rotation():
    """Exact synthetic tracks with 20 % outliers: a 0.5 deg rotation error costs more than the truth,
    at any translation scale (the depths absorb it)."""
    rng = np.random.default_rng(0)
    K = np.array([[300.0, 0, 160], [0, 300.0, 120], [0, 0, 1]])
    N = 500
    uv0 = rng.uniform([0, 0], [320, 240], (N, 2))
    z = rng.uniform(1.0, 4.0, N)
    X = np.c_[(uv0 - K[:2, 2]) / K[0, 0], np.ones(N)] * z[:, None]
    T = np.tile(np.eye(4), (3, 1, 1))
    for i, ang in ((1, 0.05), (2, 0.1)):
        T[i, :3, :3] = so3_exp(np.array([0.0, ang, 0.02]))
        T[i, :3, 3] = [-0.1 * i, 0.0, 0.02]
    obs = np.full((3, N, 2), np.nan)
    for i in (1, 2):
        Xc = X @ T[i, :3, :3].T + T[i, :3, 3]
        obs[i] = Xc[:, :2] / Xc[:, 2:] * K[0, 0] + K[:2, 2] + rng.normal(0, 0.3, (N, 2))
    obs[1:, : N // 5] += rng.uniform(-20, 20, (2, N // 5, 2))  # outliers
    c_true = track_cost(K, T, uv0, obs, 1.0)
    T_bad = T.copy()
    T_bad[2, :3, :3] = so3_exp(np.array([0.0, 0.0, np.radians(0.5)])) @ T[2, :3, :3]
    T_scaled = T.copy()
    T_scaled[:, :3, 3] *= 3.0
    assert track_cost(K, T_scaled, uv0, obs, 1.0) == pytest.approx(c_true, rel=1e-3)
    # measured: 1.19x the true cost (600 vs 506)
    assert track_cost(K, T_bad, uv0, obs, 1.0) > 1.1 * c_true


def test_hypotheses_are_deterministic_and_distinct(pair):
    K, fw, ok, _ = pair
    cfg = dataclasses.replace(load_config(None, [], mode="mono").encoder, mono_two_view_hypotheses=6)
    uva, uvb, _ = random_flow_matches(fw, ok, None, 3000, np.random.default_rng(0))
    first = two_view_pose(K, uva, uvb, 1.0, 30, 1.0)
    h1 = two_view_hypotheses(K, uva, uvb, first, cfg, np.random.default_rng(3))
    h2 = two_view_hypotheses(K, uva, uvb, first, cfg, np.random.default_rng(3))
    assert h1[0] is first and len(h1) >= 4  # measured 6
    assert all(np.array_equal(a.T_b_a, b.T_b_a) for a, b in zip(h1, h2))
    assert min(rotation_deg(a.T_b_a, b.T_b_a) for i, a in enumerate(h1) for b in h1[:i]) > 0.02


def test_chosen_two_view_rotation_is_stable_across_seeds(pair):
    """Per seed (the sampled matches and the orders): the hypothesis of least cost over all sampled
    tracks. The first hypothesis alone (today's encoder) follows the sample; the chosen one less."""
    K, fw, ok, T_gt = pair
    cfg = dataclasses.replace(load_config(None, [], mode="mono").encoder, mono_two_view_hypotheses=8)
    first_err, chosen_err = [], []
    for seed in range(5):
        rng = np.random.default_rng(seed)
        uva, uvb, _ = random_flow_matches(fw, ok, None, 3000, rng)
        first = two_view_pose(K, uva, uvb, 1.0, 30, 1.0)
        hyps = two_view_hypotheses(K, uva, uvb, first, cfg, rng)
        tracks, _, _ = random_flow_matches(fw, ok, None, 3000, rng)
        obs = track_observations(tracks, [None, fw], [None, ok], fw.shape[1], fw.shape[0])
        costs = [track_cost(K, np.stack([np.eye(4), h.T_b_a]), tracks, obs, 1.0) for h in hyps]
        first_err.append(rotation_deg(first.T_b_a, T_gt))
        chosen_err.append(rotation_deg(hyps[int(np.argmin(costs))].T_b_a, T_gt))
    # measured: first 0.15-1.85 deg (mean 0.93), chosen 0.13-0.81 (mean 0.51); the ground truth's cost is
    # 30-40 % below every hypothesis's (no hypothesis is exact: the encoder's BA refines the chosen one)
    assert max(chosen_err) < 0.9, (first_err, chosen_err)
    assert np.mean(chosen_err) < 0.7 * np.mean(first_err), (first_err, chosen_err)


@pytest.mark.slow
def test_encoder_rotations_with_hypotheses_are_stable(orbit):
    frames = [orbit[4 * k] for k in range(7)]  # 36.7 deg of rotation, two-view parallax ~12 deg
    gt = [f.T_world_cam_gt for f in frames]
    R_gt = [(invert_T(gt[0]) @ T)[:3, :3] for T in gt]  # R_0_i
    cfg = load_config(None, ["encoder.mono_two_view_hypotheses=8"], mode="mono")
    flow = make_flow_estimator(cfg.flow)
    errs = []
    for seed in range(3):
        enc = MonoEncoder(cfg.encoder, flow, seed=seed).encode(frames)
        assert len(enc.meta["hypotheses"]) >= 4
        R = enc.T_local_cam[:, :3, :3]  # R_0_i
        errs.append(np.mean([np.degrees(np.linalg.norm(so3_log(R[i] @ R_gt[i].T))) for i in range(1, 7)]))
    # measured 0.062 / 0.132 / 0.078 deg for seeds 0-2 (the default, one hypothesis: 0.130 / 0.032 / 0.268)
    assert max(errs) < 0.17, errs
    assert np.ptp(errs) < 0.12, errs
