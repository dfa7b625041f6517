"""The translation-stretch factors (gsslam.factors.stretch): Jacobians against numerical derivatives
(submaps in GTSAM's right chart, stretches as plain vectors), and agreement with the plain factors at
stretch 0 and at the stretched local poses."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import S, T

from gsslam.factors import (
    make_flow_factor,
    make_point_factor,
    make_ray_point_factor,
    make_submap_alignment_factor,
    to_gtsam,
    to_matrix,
)
from gsslam.factors.stretch import (
    make_stretch_prior_factor,
    make_stretched_alignment_factor,
    make_stretched_flow_factor,
    make_stretched_point_factor,
    make_stretched_ray_point_factor,
    stretched,
)
from helpers.factors import random_value


def _dim(values, key) -> int:
    try:
        return values.atSimilarity3(key).dim()
    except RuntimeError:
        return len(values.atVector(key))


def _analytic(factor, values) -> list[np.ndarray]:
    J = np.asarray(factor.linearize(values).jacobian()[0])
    out, c = [], 0
    for k in factor.keys():
        d = _dim(values, k)
        out.append(J[:, c : c + d])
        c += d
    return out


def _numeric(factor, values, delta=1e-6) -> list[np.ndarray]:
    out = []
    for k in factor.keys():
        cols = []
        for j in range(_dim(values, k)):
            errs = []
            for sgn in (1.0, -1.0):
                v = gtsam.Values(values)
                xi = np.zeros(_dim(values, k))
                xi[j] = sgn * delta
                try:
                    v.update(k, values.atSimilarity3(k).retract(xi))
                except RuntimeError:
                    v.update(k, values.atVector(k) + xi)
                errs.append(factor.whitenedError(v))
            cols.append((errs[0] - errs[1]) / (2 * delta))
        out.append(np.stack(cols, axis=1))
    return out


def _assert_jacobians(factor, values, atol=1e-5):
    for Ja, Jn in zip(_analytic(factor, values), _numeric(factor, values)):
        np.testing.assert_allclose(Ja, Jn, atol=atol * max(1.0, np.abs(Jn).max()))


def _rigid(rng):
    return gtsam.Pose3(gtsam.Rot3.Expmap(rng.uniform(-1, 1, 3)), rng.uniform(-1, 1, 3)).matrix()


def _values(rng, stretches=(0.08, -0.11)):
    v = gtsam.Values()
    for i, s in enumerate(stretches):
        v.insert(S(i), random_value(rng, "sim3"))
        v.insert(T(i), np.array([s]))
    return v


def test_alignment_jacobians_and_twin():
    rng = np.random.default_rng(21)
    Z = _rigid(rng)
    f = make_stretched_alignment_factor(S(0), S(1), T(0), Z, 0.01, 0.02)
    v = _values(rng)
    _assert_jacobians(f, v)
    plain = make_submap_alignment_factor(S(0), S(1), stretched(Z, 0.08), 0.01, 0.02, "sim3")
    np.testing.assert_allclose(f.unwhitenedError(v), plain.unwhitenedError(v), atol=1e-12)


def test_point_jacobians_and_twin():
    rng = np.random.default_rng(22)
    P, o, X_b = rng.normal(size=(20, 3)) * 2, rng.normal(size=(20, 3)), rng.normal(size=(20, 3)) * 2
    sig = rng.uniform(0.01, 0.1, 20)
    f = make_stretched_point_factor(S(0), S(1), T(0), P, o, X_b, sig)
    v = _values(rng)
    _assert_jacobians(f, v)
    plain = make_point_factor(S(0), S(1), P + np.exp(0.08) * o, X_b, sig, "sim3")
    np.testing.assert_allclose(f.unwhitenedError(v), plain.unwhitenedError(v), atol=1e-12)
    one = make_stretched_point_factor(S(0), S(1), T(0), P, o[0], X_b, sig)  # one offset for all points
    twin = make_stretched_point_factor(S(0), S(1), T(0), P, np.repeat(o[:1], 20, 0), X_b, sig)
    np.testing.assert_allclose(one.unwhitenedError(v), twin.unwhitenedError(v))


def _flow_case(rng):
    K = np.array([[500.0, 0, 320], [0, 480.0, 240], [0, 0, 1]])
    v = _values(rng)
    La, Lb = _rigid(rng), _rigid(rng)
    Ma = to_matrix(v.atSimilarity3(S(0))) @ stretched(La, 0.08)
    Ma[:3, :3] /= np.cbrt(np.linalg.det(Ma[:3, :3]))
    delta = gtsam.Pose3(gtsam.Rot3.Expmap(rng.uniform(-0.1, 0.1, 3)), rng.uniform(-0.3, 0.3, 3)).matrix()
    Tb = Ma @ delta @ np.linalg.inv(stretched(Lb, -0.11)) @ np.diag([1.3, 1.3, 1.3, 1.0])
    v.update(S(1), to_gtsam(Tb, "sim3"))
    uv = rng.uniform([0, 0], [640, 480], (50, 2))
    d = rng.uniform(2.0, 6.0, 50)
    return v, K, La, Lb, uv, d


@pytest.mark.parametrize("robust", [False, True])
def test_flow_jacobians_and_twin(robust):
    rng = np.random.default_rng(23)
    v, K, La, Lb, uv, d = _flow_case(rng)
    w = rng.uniform(0.2, 1, 50)
    probe = make_flow_factor(S(0), S(1), uv, d, uv, K, group="sim3", L_a=stretched(La, 0.08),
                             L_b=stretched(Lb, -0.11), robust=False)  # fmt: skip
    uv_t = uv + probe.unwhitenedError(v).reshape(-1, 2) + rng.normal(scale=1.0, size=(50, 2))
    args = (uv, d, uv_t, K, 1.5, w)
    f = make_stretched_flow_factor(S(0), S(1), T(0), T(1), *args, L_a=La, L_b=Lb, robust=robust)
    plain = make_flow_factor(S(0), S(1), *args, group="sim3", L_a=stretched(La, 0.08),
                             L_b=stretched(Lb, -0.11), robust=robust)  # fmt: skip
    np.testing.assert_allclose(f.unwhitenedError(v), plain.unwhitenedError(v), atol=1e-9)
    if not robust:  # IRLS weights are held constant in the Jacobian: compare the plain residual's
        _assert_jacobians(f, v, atol=1e-4)
    for Js, Jp in zip(_analytic(f, v)[:2], _analytic(plain, v)):
        np.testing.assert_allclose(Js, Jp, atol=1e-9)


def test_flow_at_zero_stretch_is_the_plain_factor():
    rng = np.random.default_rng(24)
    v, K, La, Lb, uv, d = _flow_case(rng)
    v.update(T(0), np.zeros(1))
    v.update(T(1), np.zeros(1))
    uv_t = uv + rng.normal(scale=3.0, size=(50, 2))
    f = make_stretched_flow_factor(S(0), S(1), T(0), T(1), uv, d, uv_t, K, L_a=La, L_b=Lb)
    plain = make_flow_factor(S(0), S(1), uv, d, uv_t, K, group="sim3", L_a=La, L_b=Lb)
    np.testing.assert_allclose(f.unwhitenedError(v), plain.unwhitenedError(v), atol=1e-12)


def test_stretch_prior():
    v = gtsam.Values()
    v.insert(T(3), np.array([0.14]))
    f = make_stretch_prior_factor(T(3), 0.07)
    assert np.isclose(f.error(v), 0.5 * 2.0**2)


@pytest.mark.parametrize("dcs_phi", [0.0, 2.0])
def test_ray_point_jacobians_and_twin(dcs_phi):
    rng = np.random.default_rng(25)
    P_a, P_b = rng.normal(size=(20, 3)) + [0, 0, 4], rng.normal(size=(20, 3)) + [0, 0, 4]
    o_a, o_b = rng.normal(size=(20, 3)) * 0.3, rng.normal(size=(20, 3)) * 0.3
    sr, sp = rng.uniform(0.05, 0.2, 20), rng.uniform(0.01, 0.03, 20)
    f = make_stretched_ray_point_factor(S(0), S(1), T(0), T(1), P_a, o_a, P_b, o_b, sr, sp, dcs_phi)
    v = _values(rng)
    if dcs_phi == 0:  # (the robust kernel reweights the linearisation: compared through the twin below)
        _assert_jacobians(f, v)
    v0 = gtsam.Values(v)  # at stretch 0 it is the plain factor on the unstretched points
    v0.update(T(0), np.zeros(1))
    v0.update(T(1), np.zeros(1))
    plain = make_ray_point_factor(S(0), S(1), P_a + o_a, P_b + o_b, sr, sp, dcs_phi)
    np.testing.assert_allclose(f.error(v0), plain.error(v0), rtol=1e-12)
