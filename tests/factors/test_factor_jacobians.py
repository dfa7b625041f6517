"""Every factor's analytic Jacobian against gtsam.utils.numerical_derivative, away from identity."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import S

from gsslam.factors import (
    make_depth_prior_factor,
    make_flow_factor,
    make_keyframe_pose_factor,
    make_point_factor,
    make_relative_point_factor,
    make_scale_factor,
    make_scale_prior_factor,
    make_submap_alignment_factor,
    to_gtsam,
    to_matrix,
)
from helpers.factors import analytic_jacobians, numeric_jacobians, random_value

GROUPS = ["pose3", "sim3"]


def _values(rng, group, n=2):
    v = gtsam.Values()
    for i in range(n):
        v.insert(S(i), random_value(rng, group))
    return v


def _assert_jacobians(factor, values, atol=1e-5):
    for Ja, Jn in zip(analytic_jacobians(factor, values), numeric_jacobians(factor, values)):
        scale = max(1.0, np.abs(Jn).max())
        np.testing.assert_allclose(Ja, Jn, atol=atol * scale)


def _rigid(rng):
    return gtsam.Pose3(gtsam.Rot3.Expmap(rng.uniform(-1, 1, 3)), rng.uniform(-1, 1, 3)).matrix()


@pytest.mark.parametrize("group", GROUPS)
def test_alignment_jacobians(group):
    rng = np.random.default_rng(1)
    f = make_submap_alignment_factor(S(0), S(1), _rigid(rng), 0.01, 0.02, group)
    _assert_jacobians(f, _values(rng, group))


@pytest.mark.parametrize("group", GROUPS)
def test_point_jacobians(group):
    rng = np.random.default_rng(2)
    X_a, X_b = rng.normal(size=(20, 3)) * 3, rng.normal(size=(20, 3)) * 3
    f = make_point_factor(S(0), S(1), X_a, X_b, rng.uniform(0.01, 0.1, 20), group)
    _assert_jacobians(f, _values(rng, group))


def test_relative_point_jacobians():
    rng = np.random.default_rng(12)
    X_a, X_b = rng.normal(size=(20, 3)) * 3, rng.normal(size=(20, 3)) * 3
    f = make_relative_point_factor(S(0), S(1), X_a, X_b, rng.uniform(0.01, 0.1, 20))
    _assert_jacobians(f, _values(rng, "sim3"))


def test_relative_point_residual_ignores_a_common_scale():
    """Scaling both submaps (and the world) leaves the residual in submap-a units unchanged."""
    rng = np.random.default_rng(13)
    X_a, X_b = rng.normal(size=(20, 3)), rng.normal(size=(20, 3))
    rel, world = make_relative_point_factor(S(0), S(1), X_a, X_b, 0.1), make_point_factor(S(0), S(1), X_a, X_b, 0.1)
    v = _values(rng, "sim3")
    shrunk = gtsam.Values()
    for k in (S(0), S(1)):  # the world shrunk by 2: S' = diag(0.5, 0.5, 0.5, 1) S
        shrunk.insert(k, to_gtsam(np.diag([0.5, 0.5, 0.5, 1.0]) @ to_matrix(v.atSimilarity3(k)), "sim3"))
    assert np.isclose(rel.error(shrunk), rel.error(v))
    assert np.isclose(world.error(shrunk), 0.25 * world.error(v))  # the world-unit factor gains by shrinking


def _flow_case(rng, group, offsets):
    """Values and a flow pair whose points are in front of both cameras (with some noise)."""
    K = np.array([[500.0, 0, 320], [0, 480.0, 240], [0, 0, 1]])
    values = gtsam.Values()
    Ta = random_value(rng, group)
    values.insert(S(0), Ta)
    La = _rigid(rng) if offsets else np.eye(4)
    Lb = _rigid(rng) if offsets else np.eye(4)
    # camera b = camera a moved a little, so the points stay visible
    from gsslam.factors import to_gtsam, to_matrix

    Ma = to_matrix(Ta) @ La
    delta = gtsam.Pose3(gtsam.Rot3.Expmap(rng.uniform(-0.1, 0.1, 3)), rng.uniform(-0.3, 0.3, 3)).matrix()
    Mb = Ma @ delta
    Tb = Mb @ np.linalg.inv(Lb)
    if group == "sim3":
        Tb = Tb @ np.diag([1.3, 1.3, 1.3, 1.0])  # a different scale for b
    values.insert(S(1), to_gtsam(Tb, group))
    uv = rng.uniform([0, 0], [640, 480], (50, 2))
    d = rng.uniform(2.0, 6.0, 50)
    probe = make_flow_factor(S(0), S(1), uv, d, uv, K, group=group, L_a=La, L_b=Lb, robust=False)
    proj = uv + probe.unwhitenedError(values).reshape(-1, 2)  # where the points really land in b
    uv_t = proj + rng.normal(scale=1.0, size=(50, 2))
    return values, uv, d, uv_t, K, La, Lb


@pytest.mark.parametrize("group", GROUPS)
@pytest.mark.parametrize("offsets", [False, True])
def test_flow_jacobians(group, offsets):
    rng = np.random.default_rng(3)
    values, uv, d, uv_t, K, La, Lb = _flow_case(rng, group, offsets)
    f = make_flow_factor(
        S(0), S(1), uv, d, uv_t, K, 1.5, rng.uniform(0.2, 1, 50), group=group, L_a=La, L_b=Lb, robust=False
    )
    _assert_jacobians(f, values, atol=1e-4)


@pytest.mark.parametrize("group", GROUPS)
def test_flow_robust_jacobian_is_irls_weighted(group):
    """With robust weights, rows are the plain Jacobian scaled by sqrt(weight) of the current error."""
    from gsslam.factors import mixture_weights

    rng = np.random.default_rng(4)
    values, uv, d, uv_t, K, _, _ = _flow_case(rng, group, False)
    uv_t[:10] += 80.0  # outliers
    plain = make_flow_factor(S(0), S(1), uv, d, uv_t, K, 2.0, group=group, robust=False)
    robust = make_flow_factor(
        S(0), S(1), uv, d, uv_t, K, 2.0, group=group, inlier_prior=0.8, outlier_range_px=60.0
    )
    e = plain.whitenedError(values).reshape(-1, 2) * 2.0
    w = mixture_weights(e, 2.0, 0.8, 60.0)
    assert w[:10].max() < 1e-3 < 0.5 < np.median(w[10:])
    for Jp, Jr in zip(analytic_jacobians(plain, values), analytic_jacobians(robust, values)):
        np.testing.assert_allclose(Jr, Jp * np.repeat(np.sqrt(w), 2)[:, None], atol=1e-9)
    np.testing.assert_allclose(
        robust.whitenedError(values), plain.whitenedError(values) * np.repeat(np.sqrt(w), 2)
    )


def test_scale_factors_jacobians():
    rng = np.random.default_rng(5)
    values = _values(rng, "sim3")
    _assert_jacobians(make_scale_factor(S(0), S(1), 0.3, 0.05), values)
    _assert_jacobians(make_scale_prior_factor(S(1), 1.2, 0.01), values)
    z = rng.uniform(1, 3, 30)
    _assert_jacobians(make_depth_prior_factor(S(0), z, z * rng.uniform(0.8, 1.2, 30), 0.05), values)


@pytest.mark.parametrize("group", GROUPS)
def test_keyframe_pose_jacobians(group):
    rng = np.random.default_rng(7)
    f = make_keyframe_pose_factor(S(0), _rigid(rng), _rigid(rng), 0.01, 0.02, group)
    _assert_jacobians(f, _values(rng, group, n=1))


def test_keyframe_pose_residual_is_zero_at_the_measured_pose():
    rng = np.random.default_rng(8)
    L, T = _rigid(rng), _rigid(rng)
    # the submap that puts the keyframe exactly at T, with scale 2.5: S = T L^-1 with t_L scaled
    Ls = L.copy()
    Ls[:3, 3] *= 2.5
    S_mat = T @ np.linalg.inv(Ls)
    value = gtsam.Similarity3(gtsam.Rot3(S_mat[:3, :3]), S_mat[:3, 3] / 2.5, 2.5)
    v = gtsam.Values()
    v.insert(S(0), value)
    f = make_keyframe_pose_factor(S(0), L, T, 0.01, 0.02, "sim3")
    np.testing.assert_allclose(f.unwhitenedError(v), np.zeros(6), atol=1e-9)


@pytest.mark.parametrize("group", GROUPS)
def test_keyframe_tie_jacobians(group):
    from gsslam.factors import make_keyframe_tie_factor

    rng = np.random.default_rng(11)
    v = _values(rng, group, n=1)
    v.insert(S(1), random_value(rng, "pose3"))  # the keyframe's body pose variable (Pose3)
    f = make_keyframe_tie_factor(S(0), S(1), _rigid(rng), _rigid(rng), 0.01, 0.02, group)
    _assert_jacobians(f, v)


def test_keyframe_tie_is_zero_when_the_body_pose_matches_the_submap():
    from gsslam.factors import make_keyframe_tie_factor, to_matrix

    rng = np.random.default_rng(12)
    L, E = _rigid(rng), _rigid(rng)  # T_local_cam, T_cam_body
    Sv = random_value(rng, "sim3")
    T = to_matrix(Sv) @ L  # [[s R, t], [0, 1]]
    T[:3, :3] /= np.cbrt(np.linalg.det(T[:3, :3]))  # rigid(S L)
    v = gtsam.Values()
    v.insert(S(0), Sv)
    v.insert(S(1), gtsam.Pose3(T @ E))
    f = make_keyframe_tie_factor(S(0), S(1), L, E, 0.01, 0.02, "sim3")
    np.testing.assert_allclose(f.unwhitenedError(v), np.zeros(6), atol=1e-9)


def test_keyframe_tie_does_not_prefer_a_world_scale():
    """The tie's residual is in submap units: moving the whole world by a Sim(3) (both the submap and
    the body pose) leaves it unchanged; in world units it would shrink with the world's scale, and
    against metric IMU positions the optimum would shrink every submap (5.5 % on teddy-200). The
    extrinsic's lever arm is metric and does not scale with the world: it is 0 here."""
    from gsslam.factors import make_keyframe_tie_factor, to_matrix

    rng = np.random.default_rng(13)
    L, E = _rigid(rng), _rigid(rng)
    E[:3, 3] = 0.0
    Sv, X = random_value(rng, "sim3"), gtsam.Pose3(_rigid(rng))
    f = make_keyframe_tie_factor(S(0), S(1), L, E, 0.01, 0.02, "sim3")
    v = gtsam.Values()
    v.insert(S(0), Sv)
    v.insert(S(1), X)
    r = f.unwhitenedError(v)
    assert np.linalg.norm(r[3:]) > 0.1  # away from zero, so that a scaling would show
    for k in (0.25, 3.0):
        G = gtsam.Similarity3(gtsam.Rot3.Expmap(rng.uniform(-1, 1, 3)), rng.uniform(-1, 1, 3), k)
        Gm = to_matrix(G)
        Xm = X.matrix()
        Xk = np.eye(4)
        Xk[:3, :3] = Gm[:3, :3] / k @ Xm[:3, :3]
        Xk[:3, 3] = Gm[:3, :3] @ Xm[:3, 3] + Gm[:3, 3]
        w = gtsam.Values()
        w.insert(S(0), G.compose(Sv))
        w.insert(S(1), gtsam.Pose3(Xk))
        np.testing.assert_allclose(f.unwhitenedError(w), r, atol=1e-9)


def _spd(rng, n=6):
    A = rng.normal(size=(n, n))
    return A @ A.T + n * np.eye(n)


@pytest.mark.parametrize("group", GROUPS)
def test_relative_pose_jacobians(group):
    from gsslam.factors import make_relative_pose_factor

    rng = np.random.default_rng(21)
    f = make_relative_pose_factor(S(0), S(1), _rigid(rng), _spd(rng) * 100.0, 0.0, group)
    _assert_jacobians(f, _values(rng, group))


def test_relative_pose_is_whitened_by_its_information_and_robust():
    """Zero at the measured pose; the error is 0.5 d^T Lambda d for a small offset d; Huber caps an outlier."""
    from gsslam.factors import make_relative_pose_factor

    rng = np.random.default_rng(22)
    Z, info = _rigid(rng), _spd(rng) * 1e4
    v = gtsam.Values()
    A = random_value(rng, "sim3")
    v.insert(S(0), A)
    v.insert(S(1), to_gtsam(to_matrix(A) @ Z, "sim3"))
    plain = make_relative_pose_factor(S(0), S(1), Z, info, 0.0)
    robust = make_relative_pose_factor(S(0), S(1), Z, info, 3.0)
    assert plain.error(v) < 1e-12
    d = rng.normal(size=6) * 1e-4  # (omega, u): right perturbation of the measurement
    moved = gtsam.Values()
    moved.insert(S(0), A)
    moved.insert(S(1), to_gtsam(to_matrix(A) @ Z @ gtsam.Pose3.Expmap(d).matrix(), "sim3"))
    assert np.isclose(plain.error(moved), 0.5 * d @ info @ d, rtol=1e-3)
    far = gtsam.Values()
    far.insert(S(0), A)
    far.insert(S(1), to_gtsam(to_matrix(A) @ Z @ gtsam.Pose3.Expmap(d * 1000).matrix(), "sim3"))
    assert robust.error(far) < 0.2 * plain.error(far)  # Huber: linear, not quadratic, far out
