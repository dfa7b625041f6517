"""A keyframe pair's pose from colour flow and depth jointly: one robust Gauss-Newton over se(3).

On keyframe pairs of TUM teddy, PnP on forward-backward-checked flow is better in rotation and
point-to-plane ICP on depth better in translation (docs/results.md, "RGB-D keyframe poses from flow and
depth, session 8"). Both are least-squares problems in the same six unknowns, ``T_tgt_src``, so their
residuals are stacked and solved together:

- **flow** (the PnP inlier set, ``M`` 3D-2D matches: source points from the source depth, their flow
  targets in the target image)::

      e_m = (pi(K, T p_m) - uv_m) / sigma_px                                   [2] px / px

- **depth** (projective point-to-plane association as in :mod:`gsslam.frontend.icp`, source point ``p``
  against the target point ``q`` with normal ``n`` that it lands on)::

      r = n . (T p - q) / sigma(z),   sigma(z) = sigma0 + sigma2 z^2           [1] m / m

Both are Huber-weighted (``huber`` in units of their sigma). The flow term is scaled by ``flow_weight``:
neither term's errors are independent per point (flow of neighbouring pixels shares its DIS patch,
depth its sensor bias), so the plain sum of informations is not the right balance; the weight is
measured (docs/results.md). Perturbation: left, ``T <- exp(xi) T``, ``xi`` = (translation, rotation),
as in :mod:`gsslam.frontend.icp` (the Jacobians below are in that chart; tests compare them with
numerical derivatives). The depth term is coarse to fine (``strides``), the flow term the same at
every level.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gsslam.frontend.icp import grid_normals, strided_points
from gsslam.geometry import so3_exp, so3_log
from gsslam.types import CameraIntrinsics


@dataclass(frozen=True)
class JointPoseResult:
    T_tgt_src: np.ndarray  # [4, 4] the joint estimate (the start when not ok)
    ok: bool
    flow_matches: int  # flow inliers used (within ``inlier_px`` of the start)
    depth_points: int  # associated depth points at the finest level
    hessian: np.ndarray | None = None  # [6, 6] J^T W J of both terms at the last step (left chart)
    reason: str = ""


def _transform(T: np.ndarray, X: np.ndarray) -> np.ndarray:  # [4, 4], [M, 3] -> [M, 3]
    return X @ T[:3, :3].T + T[:3, 3]


def _point_jacobian(p: np.ndarray) -> np.ndarray:  # [M, 3] transformed points -> d p / d xi [M, 3, 6]
    J = np.zeros((len(p), 3, 6))
    J[:, 0, 0] = J[:, 1, 1] = J[:, 2, 2] = 1.0
    # d (w x p) / d w = -[p]x
    J[:, 0, 4], J[:, 0, 5] = p[:, 2], -p[:, 1]
    J[:, 1, 3], J[:, 1, 5] = -p[:, 2], p[:, 0]
    J[:, 2, 3], J[:, 2, 4] = p[:, 1], -p[:, 0]
    return J


def reprojection_residuals(
    T: np.ndarray,  # [4, 4] T_tgt_src
    X_src: np.ndarray,  # [M, 3] points in the source camera (metres)
    uv_tgt: np.ndarray,  # [M, 2] their pixels in the target image
    K: np.ndarray,  # [3, 3] target intrinsics
    sigma_px: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:  # e [M, 2], de/dxi [M, 2, 6] (left perturbation)
    p = _transform(T, X_src)
    z = np.maximum(p[:, 2], 1e-6)
    fx, fy = K[0, 0], K[1, 1]
    e = (np.stack([fx * p[:, 0] / z + K[0, 2], fy * p[:, 1] / z + K[1, 2]], 1) - uv_tgt) / sigma_px
    Jpi = np.zeros((len(p), 2, 3))
    Jpi[:, 0, 0] = fx / z
    Jpi[:, 0, 2] = -fx * p[:, 0] / z**2
    Jpi[:, 1, 1] = fy / z
    Jpi[:, 1, 2] = -fy * p[:, 1] / z**2
    return e, Jpi @ _point_jacobian(p) / sigma_px


def point_to_plane_residuals(
    T: np.ndarray,  # [4, 4] T_tgt_src
    p_src: np.ndarray,  # [M, 3] source points (metres, source camera)
    q: np.ndarray,  # [M, 3] their associated target points (target camera)
    n: np.ndarray,  # [M, 3] unit normals at q
    sigma: np.ndarray,  # [M] metres
) -> tuple[np.ndarray, np.ndarray]:  # r [M], dr/dxi [M, 6] (left perturbation)
    p = _transform(T, p_src)
    r = np.einsum("ij,ij->i", n, p - q) / sigma
    J = np.concatenate([n, np.cross(p, n)], axis=1) / sigma[:, None]
    return r, J


def flow_inliers(
    T: np.ndarray, X_src: np.ndarray, uv_tgt: np.ndarray, K: np.ndarray, threshold_px: float
) -> np.ndarray:  # [M] bool: finite matches in front of the camera, reprojected within threshold_px
    ok = np.isfinite(X_src).all(1) & np.isfinite(uv_tgt).all(1)
    e = np.full(len(X_src), np.inf)
    if ok.any():
        p = _transform(T, X_src[ok])
        front = p[:, 2] > 1e-6
        ee, _ = reprojection_residuals(T, X_src[ok], uv_tgt[ok], K)
        e[np.flatnonzero(ok)[front]] = np.linalg.norm(ee[front], axis=1)
    return e < threshold_px


def _huber(x: np.ndarray, k: float) -> np.ndarray:  # residual norms [M] -> IRLS weights [M]
    return np.minimum(1.0, k / np.maximum(x, 1e-12))


def _associate(T, src, Pt, Nt, Kt, max_dist):  # -> (source points, targets, normals) that match
    h, w = Pt.shape[:2]
    p = _transform(T, src)
    z = p[:, 2]
    front = z > 1e-3
    u = np.full(len(p), -1)
    v = np.full(len(p), -1)
    u[front] = np.rint(Kt[0, 0] * p[front, 0] / z[front] + Kt[0, 2]).astype(int)
    v[front] = np.rint(Kt[1, 1] * p[front, 1] / z[front] + Kt[1, 2]).astype(int)
    idx = np.flatnonzero(front & (u >= 0) & (u < w) & (v >= 0) & (v < h))
    q, n = Pt[v[idx], u[idx]], Nt[v[idx], u[idx]]
    good = np.isfinite(q).all(1) & np.isfinite(n).all(1)
    idx, q, n = idx[good], q[good], n[good]
    close = np.linalg.norm(p[idx] - q, axis=1) < max_dist
    return src[idx[close]], q[close], n[close]


def joint_pose(
    X_src: np.ndarray,  # [M, 3] flow matches' source points (source camera, metres; NaN allowed)
    uv_tgt: np.ndarray,  # [M, 2] their flow targets (target image pixels)
    depth_src: np.ndarray,  # [h, w] metres, NaN invalid
    depth_tgt: np.ndarray,  # [h, w] same camera and resolution
    intr: CameraIntrinsics,  # of the depth maps and of uv_tgt
    T_init: np.ndarray,  # [4, 4] T_tgt_src start: the PnP pose (its inliers are the flow term)
    flow_weight: float = 1.0,
    strides: tuple[int, ...] = (4, 2),
    iterations: int = 8,
    sigma_px: float = 1.0,
    inlier_px: float = 1.0,
    sigma0: float = 0.002,
    sigma2: float = 0.002,
    huber: float = 2.0,
    max_dist: float = 0.08,
    min_points: int = 300,
    max_step_m: float = 0.1,
    max_step_deg: float = 8.0,
) -> JointPoseResult:
    """Joint flow + depth pose ``T_tgt_src`` (module docstring); not ok (the start returned) when the
    depth has too few matches, the system is singular or the result moved far from the start."""
    T0 = np.asarray(T_init, dtype=np.float64)
    K = intr.K
    inl = flow_inliers(T0, X_src, uv_tgt, K, inlier_px)
    X, uv = X_src[inl].astype(np.float64), uv_tgt[inl].astype(np.float64)
    T = T0.copy()
    n_depth, H = 0, None
    for stride in strides:
        Ps, _ = strided_points(depth_src, intr, stride)
        Pt, Kt = strided_points(depth_tgt, intr, stride)
        Nt = grid_normals(Pt)
        src = Ps.reshape(-1, 3)
        src = src[np.isfinite(src).all(1)]
        for _ in range(iterations):
            p, q, n = _associate(T, src, Pt, Nt, Kt, max_dist)
            if len(p) < (min_points if stride == strides[-1] else min_points // 4):
                return JointPoseResult(T0, False, len(X), len(p), None, "few_points")
            r, Jd = point_to_plane_residuals(T, p, q, n, sigma0 + sigma2 * q[:, 2] ** 2)
            wd = _huber(np.abs(r), huber)
            H = (Jd * wd[:, None]).T @ Jd
            g = (Jd * wd[:, None]).T @ r
            if len(X) and flow_weight > 0:
                e, Jf = reprojection_residuals(T, X, uv, K, sigma_px)
                wf = flow_weight * _huber(np.linalg.norm(e, axis=1), huber) * (_transform(T, X)[:, 2] > 1e-6)
                Jfw = Jf * wf[:, None, None]
                H = H + np.einsum("mki,mkj->ij", Jfw, Jf)
                g = g + np.einsum("mki,mk->i", Jfw, e)
            try:
                xi = -np.linalg.solve(H, g)
            except np.linalg.LinAlgError:
                return JointPoseResult(T0, False, len(X), len(p), None, "singular")
            dT = np.eye(4)
            dT[:3, :3] = so3_exp(xi[3:])
            dT[:3, 3] = xi[:3]
            T = dT @ T
            n_depth = len(p)
            if np.linalg.norm(xi) < 1e-6:
                break
    E = np.linalg.inv(T0) @ T
    if np.linalg.norm(E[:3, 3]) > max_step_m or np.degrees(np.linalg.norm(so3_log(E[:3, :3]))) > max_step_deg:
        return JointPoseResult(T0, False, len(X), n_depth, None, "moved_far")
    return JointPoseResult(T, True, len(X), n_depth, H)
