"""Re-joining monocular chains: the pooled Sim(3) between two chains from loops verified across them,
its dense ICP refinement with a scale term, and rigid world poses through a Sim(3) chain placement."""

from __future__ import annotations

import numpy as np

from gsslam.geometry import compose_rigid, invert_T, make_T, sim3_scale, so3_exp, split_sim3, transform_points
from gsslam.loop.chain_sim3 import fit_chain_sim3, icp_sim3
from gsslam.loop.types import LoopConstraint
from helpers.loop_scenes import corner_points


def _sim3(rng, s) -> np.ndarray:
    return make_T(so3_exp(rng.normal(size=3) * 0.5), rng.normal(size=3), s)


def _corner(rng) -> np.ndarray:  # [n, 3]
    return corner_points(rng, relief=0.05, wave=9)


def test_pooled_loops_give_the_sim3_between_chains_despite_outliers():
    rng = np.random.default_rng(3)
    T_old_new = _sim3(rng, 0.6)  # the new chain runs at its own scale
    S_new = {0: _sim3(rng, 1.3), 1: _sim3(rng, 0.8)}
    S_old = {2: _sim3(rng, 1.1), 5: _sim3(rng, 0.9)}
    loops = []
    for i, m in ((0, 2), (1, 5)):
        X_new = rng.uniform(-1, 1, size=(40, 3)) + [0, 0, 3]  # chain frame of the new chain
        X_old = transform_points(T_old_new, X_new) + rng.normal(scale=0.002, size=(40, 3))
        X_i = transform_points(invert_T(S_new[i]), X_new)
        X_m = transform_points(invert_T(S_old[m]), X_old)
        X_m[:12] = rng.uniform(-2, 2, size=(12, 3))  # 30 % wrong matches
        loops.append(LoopConstraint(i, m, X_i, X_m, np.eye(4), 0.7, 0.5, 0.05))
    fit = fit_chain_sim3(loops, S_new, S_old, 0.02, 500, rng)
    assert fit is not None and fit.loops == 2 and fit.pairs == 80
    assert 52 <= fit.inliers <= 58  # the 56 true pairs (a wrong one may fall within 2 cm)
    R, t, s = split_sim3(invert_T(T_old_new) @ fit.T_old_new)
    assert abs(s - 1) < 0.002 and np.linalg.norm(t) < 0.006  # measured: 1.2e-4, 1.9e-3
    assert abs(fit.scale - 0.6) < 0.003


def test_no_loops_no_sim3():
    rng = np.random.default_rng(0)
    assert fit_chain_sim3([], {}, {}, 0.02, 100, rng) is None


def test_sim3_icp_recovers_a_perturbed_scale_and_pose():
    rng = np.random.default_rng(1)
    dst = _corner(rng)
    T_true = make_T(so3_exp(np.array([0.1, -0.2, 0.15])), np.array([0.3, -0.1, 0.2]), 1.7)
    src = transform_points(invert_T(T_true), _corner(rng))  # other samples of the same surface
    T0 = make_T(so3_exp(np.array([0.02, 0.01, -0.02])), np.zeros(3), 1.0 / 1.05) @ T_true  # 5 % off
    T, fitness = icp_sim3(T0, dst, src, 0.1)
    T, fitness = icp_sim3(T, dst, src, 0.05)
    assert fitness > 0.9
    R, t, s = split_sim3(invert_T(T_true) @ T)
    assert abs(np.log(s)) < 0.015 and np.linalg.norm(t) < 0.005  # measured 0.0085, 0.0012 (from 0.049)


def test_compose_rigid_keeps_rotations_rigid_and_scales_translations():
    rng = np.random.default_rng(2)
    S = _sim3(rng, 2.5)
    T = make_T(so3_exp(rng.normal(size=3)), rng.normal(size=3))
    P = compose_rigid(S, T)
    assert np.allclose(P[:3, :3] @ P[:3, :3].T, np.eye(3), atol=1e-12) and abs(sim3_scale(P) - 1) < 1e-12
    assert np.allclose(P[:3, 3], transform_points(S, T[:3, 3][None])[0])  # camera centre moves with S
    assert np.allclose(
        compose_rigid(make_T(S[:3, :3] / 2.5, S[:3, 3]), T), make_T(S[:3, :3] / 2.5, S[:3, 3]) @ T
    )
