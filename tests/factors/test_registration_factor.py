"""Registration factor: Jacobians against numerical derivatives; it moves the graph to the measured pose."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import S

from gsslam.factors import FactorInputError, make_registration_factor, to_gtsam, to_matrix
from helpers.factors import analytic_jacobians, numeric_jacobians, random_value
from helpers.factors import random_information as _info
from helpers.factors import random_rigid_batch as _rigid


@pytest.mark.parametrize("group", ["pose3", "sim3"])
def test_registration_jacobians(group):
    rng = np.random.default_rng(7)
    values = gtsam.Values()
    values.insert(S(0), random_value(rng, group))
    f = make_registration_factor(S(0), _rigid(rng, 3), _rigid(rng, 3), _info(rng, 3), group)
    for Ja, Jn in zip(analytic_jacobians(f, values), numeric_jacobians(f, values)):
        np.testing.assert_allclose(Ja, Jn, atol=1e-5 * max(1.0, np.abs(Jn).max()))


def test_registration_pulls_submap_to_measured_pose():
    """Keyframes measured at a known offset: the optimum is the submap that puts them there."""
    rng = np.random.default_rng(3)
    S_true = gtsam.Similarity3(gtsam.Rot3.Expmap([0.1, -0.2, 0.3]), np.array([0.5, -0.2, 1.0]), 1.3)
    T_local = _rigid(rng, 3)
    T_meas = np.stack([to_matrix(S_true) @ T for T in T_local])
    T_meas[:, :3, :3] /= 1.3  # rigid camera poses in chain units
    info = np.stack([np.eye(6) * 1e4] * 3)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(make_registration_factor(S(0), T_local, T_meas, info, "sim3"))
    v = gtsam.Values()
    v.insert(S(0), gtsam.Similarity3(gtsam.Rot3(), np.zeros(3), 1.0))
    out = gtsam.LevenbergMarquardtOptimizer(graph, v).optimize()
    np.testing.assert_allclose(to_matrix(out.atSimilarity3(S(0))), to_matrix(S_true), atol=1e-6)


def test_registration_information_weighs_the_pull():
    """Against a unit-weight prior elsewhere, a weak registration moves the submap less than a strong one."""
    T_local = np.eye(4)[None]
    T_meas = np.eye(4)[None].copy()
    T_meas[0, :3, 3] = [0.1, 0.0, 0.0]
    moved = []
    for w in (1e-2, 1e2):
        graph = gtsam.NonlinearFactorGraph()
        graph.add(gtsam.PriorFactorPose3(S(0), gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 1.0)))
        graph.add(make_registration_factor(S(0), T_local, T_meas, np.eye(6)[None] * w, "pose3"))
        v = gtsam.Values()
        v.insert(S(0), gtsam.Pose3())
        moved.append(gtsam.LevenbergMarquardtOptimizer(graph, v).optimize().atPose3(S(0)).x())
    assert moved[0] == pytest.approx(0.1 * 1e-2 / 1.01, rel=1e-3)
    assert moved[1] == pytest.approx(0.1 * 1e2 / 101, rel=1e-3)


def test_registration_rejects_bad_information():
    with pytest.raises(FactorInputError, match="positive definite"):
        make_registration_factor(S(0), np.eye(4)[None], np.eye(4)[None], np.zeros((1, 6, 6)))
    with pytest.raises(FactorInputError):
        make_registration_factor(S(0), np.eye(4)[None], np.eye(4)[None], np.eye(6)[None], "se2")
    assert to_gtsam(np.eye(4), "pose3") is not None
