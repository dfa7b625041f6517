"""The depth-aware mono loop factor (gsslam.factors.loop_rays): Jacobians, invariances, noise along rays."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import S

from gsslam.factors import make_ray_point_factor, make_relative_point_factor, to_gtsam, to_matrix
from gsslam.factors.errors import FactorInputError
from helpers.factors import analytic_jacobians, numeric_jacobians, random_value


def _values(rng):
    v = gtsam.Values()
    for i in range(2):
        v.insert(S(i), random_value(rng, "sim3"))
    return v


def _points(rng, n=20):
    return rng.normal(size=(n, 3)) + [0, 0, 4], rng.normal(size=(n, 3)) + [0, 0, 3]  # in front of both


def test_ray_point_jacobians():
    rng = np.random.default_rng(21)
    X_a, X_b = _points(rng)
    f = make_ray_point_factor(S(0), S(1), X_a, X_b, rng.uniform(0.02, 0.1, 20), rng.uniform(0.005, 0.02, 20))
    v = _values(rng)
    for Ja, Jn in zip(analytic_jacobians(f, v), numeric_jacobians(f, v)):
        np.testing.assert_allclose(Ja, Jn, atol=1e-5 * max(1.0, np.abs(Jn).max()))


def test_equal_sigmas_give_the_relative_point_factor():
    """sigma_ray == sigma_perp: the same loss as the isotropic factor in submap-a units."""
    rng = np.random.default_rng(22)
    X_a, X_b = _points(rng)
    v = _values(rng)
    ray = make_ray_point_factor(S(0), S(1), X_a, X_b, 0.05, 0.05)
    iso = make_relative_point_factor(S(0), S(1), X_a, X_b, 0.05)
    assert np.isclose(ray.error(v), iso.error(v), rtol=1e-10)


def test_residual_ignores_a_common_similarity():
    """Any Sim(3) applied to the whole world (both submaps) leaves the loop's residual unchanged."""
    rng = np.random.default_rng(23)
    X_a, X_b = _points(rng)
    f = make_ray_point_factor(S(0), S(1), X_a, X_b, 0.08, 0.02)
    v = _values(rng)
    G = to_matrix(random_value(rng, "sim3"))
    moved = gtsam.Values()
    for k in (S(0), S(1)):
        moved.insert(k, to_gtsam(G @ to_matrix(v.atSimilarity3(k)), "sim3"))
    assert f.error(v) > 1.0
    assert np.isclose(f.error(moved), f.error(v), rtol=1e-9)


def test_error_along_the_ray_costs_less_than_across():
    """A point moved along its ray by d costs (d / sigma_ray)^2 / 2, across it (d / sigma_perp)^2 / 2."""
    X_a = np.array([[0.3, -0.2, 4.0], [1.0, 0.5, 3.0], [-0.7, 0.1, 5.0]])
    u = X_a[0] / np.linalg.norm(X_a[0])
    v = gtsam.Values()
    v.insert(S(0), gtsam.Similarity3())
    v.insert(S(1), gtsam.Similarity3())
    across = np.cross(u, [0.0, 1.0, 0.0])
    across /= np.linalg.norm(across)
    for direction, sigma in ((u, 0.1), (across, 0.01)):
        X_b = X_a.copy()
        X_b[0] -= 0.05 * direction  # only point 0 is off, by 0.05
        f = make_ray_point_factor(S(0), S(1), X_a, X_b, 0.1, 0.01)
        assert np.isclose(f.error(v), 0.5 * (0.05 / sigma) ** 2)


def test_dcs_kernel_keeps_a_consistent_loop_and_caps_a_bad_one():
    """DCS with Phi = 3N: full weight while chi2 <= 3N; far beyond, the loss saturates at 1.5 Phi."""
    rng = np.random.default_rng(24)
    X_a = rng.normal(size=(30, 3)) + [0, 0, 4]
    v = gtsam.Values()
    v.insert(S(0), gtsam.Similarity3())
    v.insert(S(1), gtsam.Similarity3())
    good = X_a + 0.008 * rng.standard_normal(X_a.shape)  # chi2 ~ 0.64 x 3N at sigma 0.01
    bad = X_a + 0.2 * rng.standard_normal(X_a.shape)  # chi2 ~ 400 x 3N
    for X_b, kept in ((good, True), (bad, False)):
        plain = make_ray_point_factor(S(0), S(1), X_a, X_b, 0.01, 0.01)
        robust = make_ray_point_factor(S(0), S(1), X_a, X_b, 0.01, 0.01, dcs_phi=1.0)
        if kept:
            assert np.isclose(robust.error(v), plain.error(v))
        else:
            assert robust.error(v) < 0.01 * plain.error(v)  # measured: 134.6 vs 19188
            assert robust.error(v) <= 1.5 * 90  # DCS's loss is bounded by 1.5 Phi (Phi = 3N = 90)


def test_ray_point_rejects_bad_input():
    X = np.ones((5, 3))
    with pytest.raises(FactorInputError):
        make_ray_point_factor(S(0), S(1), X, X, 0.1, -0.1)
    with pytest.raises(FactorInputError):
        make_ray_point_factor(S(0), S(1), X, X, 0.1, 0.1, dcs_phi=-1.0)
    with pytest.raises(FactorInputError):
        make_ray_point_factor(S(0), S(1), np.zeros((5, 3)), X, 0.1, 0.1)
