"""Robustness: a wrong loop is refused before the graph or removed after it; correction propagation."""

from __future__ import annotations

import numpy as np
import pytest

from gsslam.geometry import invert_T, make_T, so3_exp, transform_points
from gsslam.loop import drift_gate, propagate_correction
from gsslam.loop.consistency import chain, relative
from helpers.loop_graph import ate, keyframe_positions, optimise
from helpers.loop_scenes import wrong_loop


def _random_sim3(rng, scale=True):
    s = float(np.exp(rng.uniform(-0.5, 0.5))) if scale else 1.0
    return make_T(so3_exp(rng.normal(size=3)), rng.normal(size=3), s)


@pytest.mark.parametrize("name", ["revisit_rgbd", "revisit_mono"])
def test_true_loops_pass_the_gate_wrong_loop_does_not(name, request):
    sm, det, est, loops = request.getfixturevalue(name)
    for loop in loops.values():
        assert drift_gate(loop, est, det.cfg)[0]
    ok, why = drift_gate(wrong_loop(sm, det), est, det.cfg)
    assert not ok and "path" in why


@pytest.mark.parametrize("name", ["revisit_rgbd", "revisit_mono"])
def test_wrong_loop_in_graph_is_rejected_after_optimisation(name, request):
    """The wrong loop slipped into the graph: check_loops names it (and only it); removing it
    and optimising again restores the loop-closed accuracy."""
    sm, det, est, loops = request.getfixturevalue(name)
    mono = name.endswith("mono")
    assert det.check_loops(loops, optimise(est, loops, mono, loop_sigma=0.005)) == []
    with_bad = dict(loops, bad=wrong_loop(sm, det))
    poses = optimise(est, with_bad, mono, loop_sigma=0.005)
    gt = keyframe_positions(dict(enumerate(sm.T_world_local_gt)), sm.encodings)
    ate_bad = ate(keyframe_positions(poses, sm.encodings), gt, mono)
    rejected_before = det.stats.rejected_after_optimisation
    assert det.check_loops(with_bad, poses) == ["bad"]
    assert det.stats.rejected_after_optimisation == rejected_before + 1
    fixed = optimise(est, loops, mono, loop_sigma=0.005)
    assert ate(keyframe_positions(fixed, sm.encodings), gt, mono) < 0.5 * ate_bad


def test_odometry_chain_composes_links(revisit_mono):
    _, det, est, _ = revisit_mono
    for a, b in [(2, 7), (7, 2), (0, 9)]:
        T, length = chain(det.odometry, a, b)
        np.testing.assert_allclose(T, relative(est, a, b), atol=1e-9)
        ids = range(min(a, b), max(a, b) + 1)
        world = sum(np.linalg.norm(est[k][:3, 3] - est[k - 1][:3, 3]) for k in list(ids)[1:])
        scale_a = np.cbrt(np.linalg.det(est[a][:3, :3]))
        assert length == pytest.approx(world / scale_a, rel=1e-9)


def test_propagate_correction_moves_points_with_their_submap():
    rng = np.random.default_rng(0)
    old = {k: _random_sim3(rng) for k in range(4)}
    new = {k: _random_sim3(rng) for k in range(3)}  # submap 3 not optimised yet: no correction
    corr = propagate_correction(old, new)
    assert sorted(corr) == [0, 1, 2]
    X_local = rng.normal(size=(20, 3))
    for k, T in corr.items():
        X_old = transform_points(old[k], X_local)
        np.testing.assert_allclose(transform_points(T, X_old), transform_points(new[k], X_local), atol=1e-9)
    np.testing.assert_allclose(propagate_correction(old, old)[1], np.eye(4), atol=1e-12)
    np.testing.assert_allclose(corr[2] @ old[2] @ invert_T(new[2]), np.eye(4), atol=1e-9)
