"""Relative registration factor: Jacobians against numerical derivatives; it follows its owner where an
absolute registration prior pulls against a loop that moved the owner."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import S

from gsslam.factors import (
    FactorInputError,
    make_registration_factor,
    make_relative_registration_factor,
    to_gtsam,
    to_matrix,
)
from helpers.factors import analytic_jacobians, numeric_jacobians, random_value
from helpers.factors import random_information as _info
from helpers.factors import random_rigid_batch as _rigid


def _rigid_part(T):  # Sim(3) [4, 4] -> its rigid camera pose (rotation, translation unchanged)
    s = np.cbrt(np.linalg.det(T[:3, :3]))
    out = T.copy()
    out[:3, :3] /= s
    return out


@pytest.mark.parametrize("group", ["pose3", "sim3"])
def test_relative_registration_jacobians(group):
    rng = np.random.default_rng(11)
    values = gtsam.Values()
    values.insert(S(2), random_value(rng, group))
    values.insert(S(7), random_value(rng, group))
    f = make_relative_registration_factor(S(2), S(7), _rigid(rng, 3), _rigid(rng, 3), _info(rng, 3), group)
    for Ja, Jn in zip(analytic_jacobians(f, values), numeric_jacobians(f, values)):
        np.testing.assert_allclose(Ja, Jn, atol=1e-5 * max(1.0, np.abs(Jn).max()))


def test_relative_registration_is_zero_at_the_measurement_and_invariant_to_a_common_motion():
    """Measured as ``S_o^-1 S_n L``: zero there, and still zero after both submaps move by one Sim(3)."""
    rng = np.random.default_rng(5)
    So, Sn = (to_matrix(random_value(rng, "sim3")) for _ in range(2))
    L = _rigid(rng, 2)
    T_meas = np.stack([_rigid_part(np.linalg.inv(So) @ Sn @ T) for T in L])
    f = make_relative_registration_factor(S(0), S(1), L, T_meas, _info(rng, 2), "sim3")
    G = to_matrix(random_value(rng, "sim3"))
    for A in (np.eye(4), G):
        v = gtsam.Values()
        v.insert(S(0), to_gtsam(A @ So, "sim3"))
        v.insert(S(1), to_gtsam(A @ Sn, "sim3"))
        np.testing.assert_allclose(f.unwhitenedError(v), 0.0, atol=1e-9)


def _owner_moved_by_a_loop(relative: bool) -> np.ndarray:
    """Owner o (S0, gauge) and new submap n (S1) chained by odometry that is 0.1 off in x; a registration
    of n's keyframe against o's map says where n truly is. Then a loop moves o by 0.2 in y (a strong
    prior: the loop's correction of o). Returns n's translation at the optimum."""
    L = np.eye(4)[None]
    So_at_reg, Sn_true = np.eye(4), np.eye(4)
    Sn_true[:3, 3] = [1.0, 0.0, 0.0]
    info = np.eye(6)[None] * 1e4
    graph = gtsam.NonlinearFactorGraph()
    odo = gtsam.Pose3(gtsam.Rot3(), np.array([1.1, 0.0, 0.0]))
    graph.add(gtsam.BetweenFactorPose3(S(0), S(1), odo, gtsam.noiseModel.Isotropic.Sigma(6, 0.1)))
    loop = gtsam.Pose3(gtsam.Rot3(), np.array([0.0, 0.2, 0.0]))
    graph.add(gtsam.PriorFactorPose3(S(0), loop, gtsam.noiseModel.Isotropic.Sigma(6, 1e-4)))
    if relative:
        T_o_cam = np.linalg.inv(So_at_reg) @ Sn_true @ L[0]
        graph.add(make_relative_registration_factor(S(0), S(1), L, T_o_cam[None], info, "pose3"))
    else:
        graph.add(make_registration_factor(S(1), L, (Sn_true @ L[0])[None], info, "pose3"))
    v = gtsam.Values()
    v.insert(S(0), gtsam.Pose3())
    v.insert(S(1), odo)
    out = gtsam.LevenbergMarquardtOptimizer(graph, v).optimize()
    return np.asarray(out.atPose3(S(1)).translation())


def test_relative_registration_moves_with_its_owner():
    """The loop moves the owner by 0.2 in y: the relative registration carries n along (1.0, 0.2), the
    absolute prior holds n where the map was (1.0, 0.0), against the loop (the odometry, 100x weaker than
    the registration, moves it by 1 % of the loop's 0.2)."""
    np.testing.assert_allclose(_owner_moved_by_a_loop(relative=True), [1.0, 0.2, 0.0], atol=2e-3)
    np.testing.assert_allclose(_owner_moved_by_a_loop(relative=False), [1.0, 0.0, 0.0], atol=2.5e-3)


def test_relative_registration_rejects_bad_input():
    with pytest.raises(FactorInputError, match="must differ"):
        make_relative_registration_factor(S(0), S(0), np.eye(4)[None], np.eye(4)[None], np.eye(6)[None])
    with pytest.raises(FactorInputError, match="positive definite"):
        make_relative_registration_factor(S(0), S(1), np.eye(4)[None], np.eye(4)[None], np.zeros((1, 6, 6)))
    with pytest.raises(FactorInputError):
        I4, I6 = np.eye(4)[None], np.eye(6)[None]
        make_relative_registration_factor(S(0), S(1), I4, I4, I6, "se2")
