"""Our factors against GTSAM's built-in twins, linearized at the same values."""

from __future__ import annotations

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, S

from gsslam.factors import make_flow_factor, make_scale_factor, make_submap_alignment_factor, to_matrix
from helpers.factors import analytic_jacobians, random_value


def _relative(rng, scale=1.0):
    R = gtsam.Rot3.Expmap(rng.uniform(-0.8, 0.8, 3))
    return gtsam.Pose3(R, rng.uniform(-1, 1, 3)), gtsam.Similarity3(R, rng.uniform(-1, 1, 3), scale)


def test_alignment_matches_between_pose3():
    rng = np.random.default_rng(10)
    Z, _ = _relative(rng)
    A = random_value(rng, "pose3")
    values = gtsam.Values()
    values.insert(S(0), A)
    values.insert(S(1), A.compose(Z).retract(rng.normal(scale=1e-9, size=6)))
    sig = np.array([0.01] * 3 + [0.02] * 3)
    ours = make_submap_alignment_factor(S(0), S(1), Z.matrix(), 0.01, 0.02, "pose3")
    twin = gtsam.BetweenFactorPose3(S(0), S(1), Z, gtsam.noiseModel.Diagonal.Sigmas(sig))
    for Jo, Jt in zip(analytic_jacobians(ours, values), analytic_jacobians(twin, values)):
        np.testing.assert_allclose(Jo, Jt, atol=1e-6)
    # and a small error gives the same residual to first order
    values.update(S(1), A.compose(Z).retract(rng.normal(scale=1e-3, size=6)))
    np.testing.assert_allclose(ours.whitenedError(values), twin.whitenedError(values), atol=2e-3)


def test_alignment_and_scale_match_between_similarity3():
    """Rows 0-5 of BetweenFactorSimilarity3 are our alignment factor, row 6 our scale factor.

    GTSAM's Sim(3) chart measures the translation error in the units of the SECOND frame (u = t / s),
    ours in the units of the first; with our translation sigma scaled by the relative scale the
    whitened systems agree.
    """
    rng = np.random.default_rng(11)
    s_rel = 1.37
    _, Zs = _relative(rng, s_rel)
    Z = to_matrix(Zs) @ np.diag([1 / s_rel] * 3 + [1.0])  # rigid part: rotation and translation of E
    A = random_value(rng, "sim3")
    values = gtsam.Values()
    values.insert(S(0), A)
    values.insert(S(1), A.compose(Zs))
    sig = np.array([0.01] * 3 + [0.02] * 3 + [0.05])
    twin = gtsam.BetweenFactorSimilarity3(S(0), S(1), Zs, gtsam.noiseModel.Diagonal.Sigmas(sig))
    align = make_submap_alignment_factor(S(0), S(1), Z, 0.01, 0.02 * s_rel, "sim3")
    scale = make_scale_factor(S(0), S(1), np.log(s_rel), 0.05)
    np.testing.assert_allclose(align.whitenedError(values), 0, atol=1e-8)
    np.testing.assert_allclose(twin.whitenedError(values), 0, atol=1e-8)
    for Ja, Js, Jt in zip(
        analytic_jacobians(align, values), analytic_jacobians(scale, values), analytic_jacobians(twin, values)
    ):
        np.testing.assert_allclose(np.vstack([Ja, Js]), Jt, atol=1e-6)


def test_flow_target_jacobian_matches_projection_factor():
    """For fixed world points, the target-pose block equals GenericProjectionFactorCal3_S2's."""
    rng = np.random.default_rng(12)
    K = np.array([[520.0, 0, 319.5], [0, 515.0, 239.5], [0, 0, 1]])
    Pa = random_value(rng, "pose3")
    Pb = Pa.compose(gtsam.Pose3(gtsam.Rot3.Expmap(rng.uniform(-0.1, 0.1, 3)), rng.uniform(-0.2, 0.2, 3)))
    uv = rng.uniform([0, 0], [640, 480], (8, 2))
    d = rng.uniform(1.5, 4.0, 8)
    uv_t = uv + rng.normal(scale=2.0, size=(8, 2))
    values = gtsam.Values()
    values.insert(S(0), Pa)
    values.insert(S(1), Pb)
    ours = make_flow_factor(S(0), S(1), uv, d, uv_t, K, 1.0, robust=False)
    J_b = analytic_jacobians(ours, values)[1]
    e = ours.whitenedError(values)
    cal = gtsam.Cal3_S2(K[0, 0], K[1, 1], 0.0, K[0, 2], K[1, 2])
    noise = gtsam.noiseModel.Unit.Create(2)
    for k in range(8):
        X = np.array([(uv[k, 0] - K[0, 2]) / K[0, 0] * d[k], (uv[k, 1] - K[1, 2]) / K[1, 1] * d[k], d[k]])
        vals = gtsam.Values()
        vals.insert(S(1), Pb)
        vals.insert(L(k), Pa.transformFrom(X))
        twin = gtsam.GenericProjectionFactorCal3_S2(uv_t[k], noise, S(1), L(k), cal)
        np.testing.assert_allclose(e[2 * k : 2 * k + 2], twin.whitenedError(vals), atol=1e-8)
        np.testing.assert_allclose(
            J_b[2 * k : 2 * k + 2], twin.linearize(vals).jacobian()[0][:, :6], atol=1e-6
        )
