"""Dense point-to-plane ICP between two depth maps (projective association), coarse to fine.

The RGB-D frontend's motion from PnP on colour flow depends on the colour camera: its intrinsics and
its registration to the depth camera. When depth is not registered to colour (Kinect v1 data such as
7-Scenes) or the colour intrinsics are wrong, PnP is biased (a colour focal length 11 % too long makes
rotations and lateral translations ~10 % too small: a trajectory that is too small). ICP uses the
depth images alone, densely, and is metric by construction; PnP only gives its starting point.

Residual per source point ``p`` (source camera, metres) and its projective partner ``q`` with normal
``n`` in the target depth map::

    r = n . (T_tgt_src p - q) / sigma(z),     sigma(z) = sigma0 + sigma2 z^2  (Kinect-like noise)

Huber-weighted Gauss-Newton on ``T_tgt_src`` with a left perturbation ``exp(xi) T`` (``xi`` =
translation, rotation): ``dr/dxi = [n, p' x n] / sigma``; its normal matrix at the last step is
returned (``IcpResult.hessian``: the information of the estimate, for a graph factor, see
:mod:`gsslam.loop.icp_loop`). Matches farther than ``max_dist`` apart or at target depth
discontinuities are dropped. The result is refused (``ok=False``) when too few points
match, when the system is ill-conditioned (a plane or a corridor: translation along it is not
observed) or when it moved far from the start.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gsslam.geometry import so3_exp, so3_log
from gsslam.types import CameraIntrinsics

TRACK_STRIDES = (16, 8)  # full-resolution 640x480 depth: 40x30 then 80x60 points (frame tracking)


@dataclass(frozen=True)
class IcpResult:
    T_tgt_src: np.ndarray  # [4, 4] refined (or the start when not ok)
    ok: bool
    inliers: int  # matched source points at the finest level
    rmse_m: float  # point-to-plane RMS of the inliers, metres
    condition: float  # smallest / largest eigenvalue of the (scaled) normal matrix
    reason: str = ""
    matches: int = 0  # flow matches in the joint solve (``matches``), 0 without
    # [6, 6] Gauss-Newton normal matrix J^T W J of the whitened residuals at the last step (finest level),
    # over the left perturbation (translation, rotation) of T_tgt_src in the target camera; None when refused
    hessian: np.ndarray | None = None


def strided_points(depth: np.ndarray, intr: CameraIntrinsics, stride: int) -> tuple[np.ndarray, np.ndarray]:
    """Point map [h', w', 3] of ``depth`` sampled every ``stride`` px, and its intrinsics matrix."""
    d = depth[stride // 2 :: stride, stride // 2 :: stride].astype(np.float64)
    h, w = d.shape
    fx, fy = intr.fx / stride, intr.fy / stride
    cx = (intr.cx - stride // 2) / stride
    cy = (intr.cy - stride // 2) / stride
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    P = np.stack([(u - cx) / fx * d, (v - cy) / fy * d, d], axis=-1)
    P[~(d > 0)] = np.nan
    return P, np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])


def grid_normals(P: np.ndarray, max_jump_rel: float = 0.05) -> np.ndarray:  # [h, w, 3] -> [h, w, 3] (NaN)
    N = np.full_like(P, np.nan)
    dx = P[1:-1, 2:] - P[1:-1, :-2]
    dy = P[2:, 1:-1] - P[:-2, 1:-1]
    n = np.cross(dx, dy)
    norm = np.linalg.norm(n, axis=-1, keepdims=True)
    z = P[1:-1, 1:-1, 2:3]
    with np.errstate(invalid="ignore", divide="ignore"):
        n = n / norm
        smooth = (np.abs(dx[..., 2:3]) < max_jump_rel * 2 * z) & (np.abs(dy[..., 2:3]) < max_jump_rel * 2 * z)
    n[~smooth[..., 0]] = np.nan
    N[1:-1, 1:-1] = n
    return N


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
    """Flow term: ``e = (pi(K, T p) - uv) / sigma_px`` and its Jacobian."""
    p = X_src @ T[:3, :3].T + T[:3, 3]
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
    """Depth term: ``r = n . (T p - q) / sigma`` and its Jacobian."""
    p = p_src @ T[:3, :3].T + T[:3, 3]
    r = np.einsum("ij,ij->i", n, p - q) / sigma
    J = np.concatenate([n, np.cross(p, n)], axis=1) / sigma[:, None]
    return r, J


def _huber(x: np.ndarray, k: float) -> np.ndarray:  # residual norms [M] -> IRLS weights [M]
    return np.minimum(1.0, k / np.maximum(x, 1e-12))


def _flow_terms(T, X, uv, K, sigma_px, huber, weight) -> tuple[np.ndarray, np.ndarray]:  # H [6, 6], g [6]
    e, J = reprojection_residuals(T, X, uv, K, sigma_px)
    w = weight * _huber(np.linalg.norm(e, axis=1), huber) * ((X @ T[2, :3] + T[2, 3]) > 1e-6)
    Jw = J * w[:, None, None]
    return np.einsum("mki,mkj->ij", Jw, J), np.einsum("mki,mk->i", Jw, e)


def icp_point_to_plane(
    depth_src: np.ndarray,  # [h, w] metres, NaN invalid
    depth_tgt: np.ndarray,  # [h, w] metres, NaN invalid (same camera and resolution)
    intr: CameraIntrinsics,  # of the depth maps
    T_init: np.ndarray,  # [4, 4] T_tgt_src start (e.g. from PnP)
    strides: tuple[int, ...] = (8, 4),
    iterations: int = 8,
    max_dist: float = 0.08,
    sigma0: float = 0.002,
    sigma2: float = 0.002,
    huber: float = 2.0,
    min_points: int = 300,
    min_condition: float = 1e-3,
    max_step_m: float = 0.1,
    max_step_deg: float = 8.0,
    matches: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,  # X_src [M, 3], uv_tgt [M, 2], K
    match_sigma_px: float = 1.0,
    match_weight: float = 1.0,
    tol: float = 1e-5,
) -> IcpResult:
    """Point-to-plane ICP ``T_tgt_src`` (module docstring); with ``matches`` the joint flow + depth pose.

    ``matches``: 3D-2D flow matches whose reprojection residuals (``match_sigma_px``, Huber, scaled by
    ``match_weight``) are stacked with the depth residuals (:mod:`gsslam.frontend.joint_pose` selects
    them). ``min_condition`` 0: no conditioning check. ``tol``: a level stops when both the translation
    (m) and the rotation (rad) step are below it."""
    T = np.asarray(T_init, dtype=np.float64).copy()
    inliers, rmse, cond = 0, float("nan"), 0.0
    n_matches = 0 if matches is None else len(matches[0])

    def _refused(n: int, reason: str) -> IcpResult:  # the start, not ok
        return IcpResult(np.asarray(T_init, float), False, n, rmse, cond, reason, n_matches)

    H = None
    for stride in strides:
        Ps, _ = strided_points(depth_src, intr, stride)
        Pt, Kt = strided_points(depth_tgt, intr, stride)
        Nt = grid_normals(Pt)
        src = Ps.reshape(-1, 3)
        src = src[np.isfinite(src).all(1)]
        h, w = Pt.shape[:2]
        for _ in range(iterations):
            p = src @ T[:3, :3].T + T[:3, 3]
            z = p[:, 2]
            front = z > 1e-3
            u = np.full(len(p), -1)
            v = np.full(len(p), -1)
            u[front] = np.rint(Kt[0, 0] * p[front, 0] / z[front] + Kt[0, 2]).astype(int)
            v[front] = np.rint(Kt[1, 1] * p[front, 1] / z[front] + Kt[1, 2]).astype(int)
            inside = front & (u >= 0) & (u < w) & (v >= 0) & (v < h)
            idx = np.flatnonzero(inside)
            q = Pt[v[idx], u[idx]]
            n = Nt[v[idx], u[idx]]
            good = np.isfinite(q).all(1) & np.isfinite(n).all(1)
            idx, q, n = idx[good], q[good], n[good]
            pp = p[idx]
            close = np.linalg.norm(pp - q, axis=1) < max_dist
            idx, q, n, pp = idx[close], q[close], n[close], pp[close]
            if len(idx) < (min_points if stride == strides[-1] else min_points // 4):
                return _refused(len(idx), "few_points")
            sig = sigma0 + sigma2 * q[:, 2] ** 2
            r, J = point_to_plane_residuals(T, src[idx], q, n, sig)  # [M], [M, 6]
            Jw = J * _huber(np.abs(r), huber)[:, None]
            H = Jw.T @ J
            g = Jw.T @ r
            if matches is not None and len(matches[0]) and match_weight > 0:
                Hm, gm = _flow_terms(T, *matches, match_sigma_px, huber, match_weight)
                H, g = H + Hm, g + gm
            # conditioning with rotation scaled by the median depth (metres vs radians)
            zm = float(np.median(q[:, 2]))
            D = np.diag([1, 1, 1, 1 / zm, 1 / zm, 1 / zm])
            ev = np.linalg.eigvalsh(D @ H @ D)
            cond = float(ev[0] / max(ev[-1], 1e-300))
            if min_condition > 0 and cond < min_condition:
                return _refused(len(idx), "ill_conditioned")
            try:
                xi = -np.linalg.solve(H, g)
            except np.linalg.LinAlgError:
                return _refused(len(idx), "singular")
            dT = np.eye(4)
            dT[:3, :3] = so3_exp(xi[3:])
            dT[:3, 3] = xi[:3]
            T = dT @ T
            inliers = len(idx)
            inl = np.abs(r) < huber
            rmse = float(np.sqrt(np.mean((r * sig)[inl] ** 2))) if inl.any() else rmse
            if np.linalg.norm(xi[:3]) < tol and np.linalg.norm(xi[3:]) < tol:
                break
    E = np.linalg.inv(np.asarray(T_init, float)) @ T
    if np.linalg.norm(E[:3, 3]) > max_step_m or np.degrees(np.linalg.norm(so3_log(E[:3, :3]))) > max_step_deg:
        return _refused(inliers, "moved_far")
    return IcpResult(T, True, inliers, rmse, cond, matches=n_matches, hessian=H)


def refine_relative_pose(
    depth_ref: np.ndarray,  # [H, W] metres, the reference keyframe
    depth_cur: np.ndarray | None,  # [H, W] metres, the tracked frame
    intr: CameraIntrinsics,
    T_ref_cur: np.ndarray,  # [4, 4] e.g. from PnP
) -> np.ndarray:  # [4, 4] T_ref_cur refined by ICP at TRACK_STRIDES, or as given when ICP refuses
    if depth_cur is None:
        return T_ref_cur
    res = icp_point_to_plane(depth_ref, depth_cur, intr, np.linalg.inv(T_ref_cur), strides=TRACK_STRIDES)
    return np.linalg.inv(res.T_tgt_src) if res.ok else T_ref_cur
