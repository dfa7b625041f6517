"""Joint flow + depth pose (frontend/joint_pose.py on icp.py's solver): Jacobians, exact and noisy synthetic
pairs, a wall."""

from __future__ import annotations

import numpy as np
import pytest

from gsslam.frontend.icp import icp_point_to_plane, point_to_plane_residuals, reprojection_residuals
from gsslam.frontend.joint_pose import joint_pose
from gsslam.frontend.pose_estimation import pnp
from gsslam.geometry import backproject, invert_T, make_T, project, so3_exp, so3_log, transform_points
from helpers.plane_scene import INTR, PlaneScene

T_B = make_T(so3_exp(np.radians([1.0, -2.0, 0.5])), np.array([0.03, -0.01, 0.02]))  # a keyframe step


def _err(T, G):  # -> (mm, deg)
    E = invert_T(G) @ T
    return 1000 * np.linalg.norm(E[:3, 3]), np.degrees(np.linalg.norm(so3_log(E[:3, :3])))


def _retract(T, xi):  # the estimator's chart: T <- exp(xi) T, xi = (translation, rotation)
    dT = make_T(so3_exp(xi[3:]), xi[:3])
    return dT @ T


def _numeric(f, T, eps=1e-6):  # central differences of f(T) [M, ...] over the 6 chart directions
    cols = []
    for k in range(6):
        d = np.zeros(6)
        d[k] = eps
        cols.append((f(_retract(T, d)) - f(_retract(T, -d))) / (2 * eps))
    return np.stack(cols, axis=-1)


def test_residual_jacobians_match_numerical_derivatives():
    rng = np.random.default_rng(3)
    T = make_T(so3_exp(rng.uniform(-0.5, 0.5, 3)), rng.uniform(-0.3, 0.3, 3))  # away from identity
    X = rng.uniform([-1, -1, 2], [1, 1, 4], (20, 3))
    uv = rng.uniform(0, 300, (20, 2))
    e, J = reprojection_residuals(T, X, uv, INTR.K, sigma_px=0.7)
    Jn = _numeric(lambda S: reprojection_residuals(S, X, uv, INTR.K, 0.7)[0], T)
    assert e.shape == (20, 2) and J.shape == (20, 2, 6)
    np.testing.assert_allclose(J, Jn, rtol=1e-5, atol=1e-4)
    q = rng.uniform([-1, -1, 2], [1, 1, 4], (20, 3))
    n = rng.normal(size=(20, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    sig = rng.uniform(0.002, 0.01, 20)
    r, Jd = point_to_plane_residuals(T, X, q, n, sig)
    Jdn = _numeric(lambda S: point_to_plane_residuals(S, X, q, n, sig)[0], T)
    assert r.shape == (20,) and Jd.shape == (20, 6)
    np.testing.assert_allclose(Jd, Jdn, rtol=1e-5, atol=1e-4)


def _pair(seed: int, depth_noise: float, flow_noise_px: float, wall: bool = False):
    """Two views of the planes scene (or a head-on wall), flow matches from the truth + noise + 20 %
    outliers, Kinect-like depth noise ``depth_noise * z^2``. -> (X, uv_tgt, depth_a, depth_b, G, PnP pose)."""
    rng = np.random.default_rng(seed)
    scene = PlaneScene(0)
    _, da = scene.render(np.eye(4))
    _, db = scene.render(T_B)
    if wall:  # a wall 2 m ahead fills the view: depth alone cannot fix motion along it
        da, db = np.full_like(da, 2.0), None
    G = invert_T(T_B)  # T_b_a: source a -> target b
    h, w = da.shape
    if wall:  # the plane z = 2 of frame a, seen from b: n_b . x = d_b
        n_b = G[:3, :3] @ np.array([0.0, 0.0, 1.0])
        d_b = n_b @ G[:3, 3] + 2.0
        pix = np.stack(np.meshgrid(np.arange(w), np.arange(h)), -1).reshape(-1, 2)
        db = (d_b / (backproject(INTR.K, pix, np.ones(h * w)) @ n_b)).reshape(h, w).astype(np.float32)
    ok = np.flatnonzero(np.isfinite(da).ravel())
    idx = rng.choice(ok, 1500, replace=False)
    v, u = np.divmod(idx, w)
    uv = np.stack([u, v], 1).astype(float)
    uvt, _ = project(INTR.K, transform_points(G, backproject(INTR.K, uv, da.ravel()[idx].astype(float))))
    uvt = uvt + flow_noise_px * rng.standard_normal(uvt.shape)
    out = rng.random(len(uvt)) < 0.2
    uvt[out] += rng.uniform(-20, 20, (int(out.sum()), 2))
    dA = (da + depth_noise * da**2 * rng.standard_normal(da.shape)).astype(np.float32)
    dB = (db + depth_noise * db**2 * rng.standard_normal(db.shape)).astype(np.float32)
    X = backproject(INTR.K, uv, dA.ravel()[idx].astype(float))
    P = pnp(X, uvt, INTR.K, 1.0, 30)
    assert P.T_tgt_src is not None
    return X, uvt, dA, dB, G, P.T_tgt_src


def test_exact_cues_give_the_exact_pose_from_a_wrong_start():
    X, uvt, dA, dB, G, _ = _pair(0, depth_noise=0.0, flow_noise_px=0.0)
    start = make_T(so3_exp(np.radians([0.3, -0.2, 0.2])), np.array([0.004, 0.003, -0.005])) @ G
    res = joint_pose(X, uvt, dA, dB, INTR, start, inlier_px=3.0)
    assert res.ok, res.reason
    dt, dr = _err(res.T_tgt_src, G)
    assert dt < 0.05 and dr < 0.002  # measured 0.0 mm, 0.0 deg
    assert res.matches > 1000 and res.inliers > 10000


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_noisy_cues_joint_pose_near_the_truth(seed):
    X, uvt, dA, dB, G, T_pnp = _pair(seed, depth_noise=0.0015, flow_noise_px=0.7)
    res = joint_pose(X, uvt, dA, dB, INTR, T_pnp)
    assert res.ok, res.reason
    dt, dr = _err(res.T_tgt_src, G)
    dt_pnp, _ = _err(T_pnp, G)
    # measured (seeds 0-2): joint 1.3 / 1.1 / 1.4 mm, 0.023 / 0.021 / 0.042 deg; PnP 6.4 / 4.2 / 3.3 mm
    assert dt < 3.0 and dr < 0.08
    assert dt < dt_pnp
    assert np.all(np.linalg.eigvalsh(res.hessian) > 0)


def test_no_flow_weight_is_point_to_plane_icp():
    X, uvt, dA, dB, G, T_pnp = _pair(1, depth_noise=0.0015, flow_noise_px=0.7)
    res = joint_pose(X, uvt, dA, dB, INTR, T_pnp, flow_weight=0.0, strides=(4, 2))
    icp = icp_point_to_plane(dA, dB, INTR, T_pnp, strides=(4, 2))
    assert res.ok and icp.ok
    dt, dr = _err(res.T_tgt_src, icp.T_tgt_src)
    assert dt < 1e-3 and dr < 1e-4


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_wall_head_on_joint_pose_beats_both_cues(seed):
    """Depth of a wall cannot fix motion along it (ICP drifts with the noisy normals); the flow can."""
    X, uvt, dA, dB, G, T_pnp = _pair(seed, depth_noise=0.0015, flow_noise_px=0.7, wall=True)
    icp = icp_point_to_plane(dA, dB, INTR, T_pnp, strides=(4, 2))
    res = joint_pose(X, uvt, dA, dB, INTR, T_pnp)
    assert res.ok, res.reason
    dt, dr = _err(res.T_tgt_src, G)
    dt_pnp, dr_pnp = _err(T_pnp, G)
    dt_icp, dr_icp = _err(icp.T_tgt_src, G)
    # measured (seeds 0-2): joint 1.7 / 1.0 / 1.1 mm, 0.003 / 0.009 / 0.026 deg; PnP 3.4-5.7 mm,
    # 0.09-0.18 deg; ICP 12-16 mm, 0.05-0.29 deg
    assert dt < 3.0 and dr < 0.05
    assert dt < min(dt_pnp, dt_icp) and dr < min(dr_pnp, dr_icp)
