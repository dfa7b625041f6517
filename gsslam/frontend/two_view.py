"""Two-view and few-view geometry for the monocular encoder: relative pose, triangulation,
model selection, dense two-view depth and a small bundle adjustment.

Poses are ``T_b_a`` (points of camera a into camera b); pixels are at the encoder's point-map
resolution; one intrinsics matrix ``K`` for all views.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np

from gsslam.geometry import invert_T

log = logging.getLogger(__name__)

ESSENTIAL_METHODS = {"ransac": cv2.RANSAC, "magsac": cv2.USAC_MAGSAC}


@dataclass
class TwoViewResult:
    T_b_a: np.ndarray | None  # [4, 4], |t| = 1 (scale unknown), None when rejected
    X_a: np.ndarray  # [M, 3] triangulated points in camera a (same arbitrary scale)
    uv_a: np.ndarray  # [M, 2] their pixels in a
    median_parallax_deg: float
    essential_inliers: int
    homography_inliers: int
    reason: str  # "ok" or why the geometry was rejected


def rays(K: np.ndarray, uv: np.ndarray) -> np.ndarray:  # [N, 2] -> [N, 3] normalized (z = 1)
    x = (uv[:, 0] - K[0, 2]) / K[0, 0]
    y = (uv[:, 1] - K[1, 2]) / K[1, 1]
    return np.stack([x, y, np.ones_like(x)], axis=1)


def triangulate_rays(
    K: np.ndarray,
    uv_a: np.ndarray,  # [N, 2]
    uv_b: np.ndarray,  # [N, 2]
    T_b_a: np.ndarray,  # [4, 4]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Midpoint triangulation: (X_a [N, 3], parallax deg [N], max reprojection error px [N]).

    Points behind either camera get NaN coordinates.
    """
    T_a_b = invert_T(T_b_a)
    da = rays(K, uv_a)
    db = rays(K, uv_b) @ T_a_b[:3, :3].T  # ray directions of b, in frame a
    c = T_a_b[:3, 3]  # centre of b in frame a
    # solve a * da - b * db = c in least squares, per point (2x2 normal equations)
    A11 = np.sum(da * da, 1)
    A12 = -np.sum(da * db, 1)
    A22 = np.sum(db * db, 1)
    r1, r2 = np.sum(da * c, 1), -np.sum(db * c, 1)
    det = A11 * A22 - A12 * A12
    with np.errstate(divide="ignore", invalid="ignore"):
        sa = (A22 * r1 - A12 * r2) / det
        sb = (A11 * r2 - A12 * r1) / det
        X = 0.5 * (sa[:, None] * da + (c + sb[:, None] * db))
        cosang = np.sum(da * db, 1) / np.sqrt(A11 * A22)
    par = np.degrees(np.arccos(np.clip(cosang, -1.0, 1.0)))
    bad = ~(sa > 0) | ~(sb > 0) | ~np.isfinite(det) | (np.abs(det) < 1e-15)
    X[bad] = np.nan
    err = np.maximum(_reproj_err(K, X, uv_a, np.eye(4)), _reproj_err(K, X, uv_b, T_b_a))
    return X, par, err


def _reproj_err(K: np.ndarray, X_a: np.ndarray, uv: np.ndarray, T_c_a: np.ndarray) -> np.ndarray:
    Xc = X_a @ T_c_a[:3, :3].T + T_c_a[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = K[0, 0] * Xc[:, 0] / Xc[:, 2] + K[0, 2]
        v = K[1, 1] * Xc[:, 1] / Xc[:, 2] + K[1, 2]
        e = np.hypot(u - uv[:, 0], v - uv[:, 1])
    e[~(Xc[:, 2] > 0)] = np.inf
    return np.nan_to_num(e, nan=np.inf)


def two_view_pose(
    K: np.ndarray,
    uv_a: np.ndarray,  # [N, 2]
    uv_b: np.ndarray,  # [N, 2]
    threshold_px: float,
    min_inliers: int,
    min_parallax_deg: float,
    method: str = "ransac",
) -> TwoViewResult:
    """Essential matrix (RANSAC) + recoverPose + checked triangulation, with model selection.

    Rejected (``T_b_a = None``) when there are too few matches or inliers, when the median
    parallax of the triangulated inliers is below ``min_parallax_deg`` (pure rotation / tiny
    baseline), or when a homography explains the matches as well as the essential matrix *and*
    the parallax is small (the two-view geometry is then not determined). ``method``: the robust
    estimator of the essential matrix, "ransac" (OpenCV's RANSAC) or "magsac" (MAGSAC++, whose
    model does not follow its random sample; docs/frontend.md).
    """
    empty = np.zeros((0, 3)), np.zeros((0, 2))
    if len(uv_a) < max(8, min_inliers):
        return TwoViewResult(None, *empty, 0.0, 0, 0, f"too few matches ({len(uv_a)})")
    pa, pb = uv_a.astype(np.float64), uv_b.astype(np.float64)
    E, mask_e = cv2.findEssentialMat(pa, pb, K, ESSENTIAL_METHODS[method], 0.999, threshold_px)
    H, mask_h = cv2.findHomography(pa, pb, cv2.RANSAC, 2.0 * threshold_px)
    n_h = int(mask_h.sum()) if mask_h is not None else 0
    if E is None or E.shape != (3, 3) or mask_e is None:
        return TwoViewResult(None, *empty, 0.0, 0, n_h, "essential matrix estimation failed")
    n_e = int(mask_e.sum())
    if n_e < min_inliers:
        return TwoViewResult(None, *empty, 0.0, n_e, n_h, f"too few essential inliers ({n_e})")
    _, R, t, mask_p = cv2.recoverPose(E, pa, pb, K, mask=mask_e.copy())
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t.reshape(3) / max(np.linalg.norm(t), 1e-12)
    inl = mask_p.reshape(-1) > 0
    X, par, err = triangulate_rays(K, pa[inl], pb[inl], T)
    good = np.isfinite(X).all(1) & (err < 2.0 * threshold_px) & (par > 0.25 * min_parallax_deg)
    med_par = float(np.median(par[np.isfinite(X).all(1)])) if np.isfinite(X).any() else 0.0
    if good.sum() < min_inliers:
        return TwoViewResult(
            None, *empty, med_par, n_e, n_h, f"too few well-triangulated points ({good.sum()})"
        )
    if med_par < min_parallax_deg:
        return TwoViewResult(None, *empty, med_par, n_e, n_h, f"low parallax ({med_par:.2f} deg)")
    if n_h >= 0.95 * n_e and med_par < 2.0 * min_parallax_deg:
        return TwoViewResult(
            None, *empty, med_par, n_e, n_h, "homography explains the motion (rotation/plane)"
        )
    return TwoViewResult(T, X[good], pa[inl][good], med_par, n_e, n_h, "ok")


def rotation_from_homography(K: np.ndarray, uv_a: np.ndarray, uv_b: np.ndarray) -> np.ndarray | None:
    """``R_b_a`` of a (near) pure rotation, ``x_b ~ K R K^-1 x_a``; None when it cannot be fitted."""
    if len(uv_a) < 8:
        return None
    H, mask = cv2.findHomography(uv_a.astype(np.float64), uv_b.astype(np.float64), cv2.RANSAC, 2.0)
    if H is None or mask is None or mask.sum() < 8:
        return None
    M = np.linalg.inv(K) @ H @ K
    U, _, Vt = np.linalg.svd(M)
    R = U @ Vt
    if np.linalg.det(R) < 0:
        R = -R
    return R


def _skew(v: np.ndarray) -> np.ndarray:  # [N, 3] -> [N, 3, 3]
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2], S[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    S[..., 1, 0], S[..., 2, 0], S[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return S


def _huber_weights(r: np.ndarray, k: float) -> np.ndarray:  # [M, 2] -> [M] IRLS weights
    n = np.linalg.norm(r, axis=1)
    return np.where(n <= k, 1.0, k / np.maximum(n, 1e-12))


def _huber_cost(r: np.ndarray, k: float) -> float:  # [M, 2]
    n = np.linalg.norm(r, axis=1)
    return float(np.sum(np.where(n <= k, 0.5 * n**2, k * (n - 0.5 * k))))


def _sum_by(group: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:  # [M], [M, C] -> [n, C]
    return np.stack([np.bincount(group, values[:, c], minlength=n) for c in range(values.shape[1])], 1)


def bundle_adjust(
    K: np.ndarray,
    T_i_0: np.ndarray,  # [F, 4, 4] initial poses (frame 0 -> frame i); T_i_0[0] = I is held fixed
    uv0: np.ndarray,  # [N, 2] track pixels in frame 0
    inv_depth: np.ndarray,  # [N] initial inverse depths in frame 0
    obs_uv: np.ndarray,  # [F, N, 2] observations (NaN where not seen)
    threshold_px: float,
    max_iterations: int = 20,
    rho_prior: np.ndarray | None = None,  # [N] inverse depths known from elsewhere (NaN: none)
    prior_sigma_rel: float | np.ndarray = 0.0,  # relative std of rho_prior: one, or [N] per track
) -> tuple[np.ndarray, np.ndarray]:
    """Joint refinement of the poses and frame-0 inverse depths: Levenberg-Marquardt with Huber
    weights (IRLS), analytic Jacobians and the Schur complement on the inverse depths.

    Each observation of track j in frame i touches one pose (6 parameters, left perturbation
    ``R <- exp(dw) R``, ``t <- t + dt``) and one inverse depth, so the depth block is diagonal and
    the reduced camera system is only ``6 (F - 1)`` wide. Frame 0 is exact (the tracks are defined
    there). Returns (T_i_0 [F, 4, 4], inv_depth [N]). The scale is a gauge freedom of this cost; the
    damping keeps it close to the initial one and callers restore it.

    With ``rho_prior`` and ``prior_sigma_rel > 0``, each track that has one also gets the residual
    ``(rho / rho_prior - 1) / prior_sigma_rel`` (in the units of a 1 px reprojection error, Huber at
    ``threshold_px`` too): the inverse depths are held to a known depth map, which fixes the scale and
    ties the translations to it. Diagonal in the depth block: the Schur complement is unchanged.
    ``prior_sigma_rel`` may be per track (the known depth's own uncertainty); a track whose sigma is
    0, NaN or infinite has no prior.
    """
    F, N = obs_uv.shape[:2]
    seen = np.isfinite(obs_uv).all(-1)  # [F, N]
    seen[0] = False
    fi, pj = np.nonzero(seen)
    if len(fi) < 6 * (F - 1) + 10:
        return T_i_0, inv_depth
    b = rays(K, uv0)  # [N, 3]
    fx, fy = K[0, 0], K[1, 1]
    target = obs_uv[fi, pj]  # [M, 2]
    R = T_i_0[:, :3, :3].copy()
    t = T_i_0[:, :3, 3].copy()
    rho = np.maximum(np.asarray(inv_depth, np.float64).copy(), 1e-6)
    P = 6 * (F - 1)
    lam_p = np.zeros(N)  # d r_prior / d rho, 0 where no prior
    off_p = np.zeros(N)  # r_prior = lam_p * rho - off_p = (rho / rho_prior - 1) / sigma
    if rho_prior is not None:
        rp = np.asarray(rho_prior, np.float64)
        sig = np.broadcast_to(np.asarray(prior_sigma_rel, np.float64), (N,))
        with np.errstate(invalid="ignore"):
            has = np.isfinite(rp) & (rp > 0) & np.isfinite(sig) & (sig > 0)
        lam_p[has] = 1.0 / (sig[has] * rp[has])
        off_p[has] = 1.0 / sig[has]

    def prior_res(rho):  # [N]: 0 where no prior
        return lam_p * rho - off_p

    def total_cost(r, rho):
        c = _huber_cost(r, threshold_px)
        if lam_p.any():
            c += _huber_cost(prior_res(rho)[:, None], threshold_px)
        return c

    def residuals(R, t, rho):
        RX = np.einsum("mij,mj->mi", R[fi], b[pj]) / rho[pj, None]
        Xc = RX + t[fi]
        z = np.where(Xc[:, 2] > 1e-9, Xc[:, 2], 1e-9)
        r = np.stack([fx * Xc[:, 0] / z + K[0, 2], fy * Xc[:, 1] / z + K[1, 2]], 1) - target
        return r, RX, Xc, z

    r, RX, Xc, z = residuals(R, t, rho)
    cost = total_cost(r, rho)
    lam = 1e-4
    for _ in range(max_iterations):
        w = _huber_weights(r, threshold_px)
        # d proj / d Xc: [M, 2, 3]
        Jx = np.zeros((len(fi), 2, 3))
        Jx[:, 0, 0], Jx[:, 0, 2] = fx / z, -fx * Xc[:, 0] / z**2
        Jx[:, 1, 1], Jx[:, 1, 2] = fy / z, -fy * Xc[:, 1] / z**2
        Jp = np.concatenate([-Jx @ _skew(RX), Jx], 2)  # [M, 2, 6]
        Jr = np.einsum("mkj,mj->mk", Jx, -RX / rho[pj, None])  # [M, 2]
        wJp = w[:, None, None] * Jp
        Hpp_m = np.einsum("mki,mkj->mij", wJp, Jp)  # [M, 6, 6]
        Hpl_m = np.einsum("mki,mk->mi", wJp, Jr)  # [M, 6]
        gp_m = np.einsum("mki,mk->mi", wJp, r)  # [M, 6]
        Hll = np.bincount(pj, w * np.sum(Jr * Jr, 1), minlength=N)
        gl = np.bincount(pj, w * np.sum(Jr * r, 1), minlength=N)
        if lam_p.any():
            rp = prior_res(rho)
            wp = _huber_weights(rp[:, None], threshold_px)
            Hll += wp * lam_p**2
            gl += wp * lam_p * rp
        Hpp = _sum_by(fi - 1, Hpp_m.reshape(-1, 36), F - 1).reshape(F - 1, 6, 6)
        gp = _sum_by(fi - 1, gp_m, F - 1)
        # dense [P, N]: few poses, N tracks; row 6 (i - 1) + c, column j
        flat = ((6 * (fi - 1))[:, None] + np.arange(6)) * N + pj[:, None]
        Hpl = np.bincount(flat.ravel(), Hpl_m.ravel(), minlength=P * N).reshape(P, N)
        Hpp_full = np.zeros((P, P))
        for k in range(F - 1):
            Hpp_full[6 * k : 6 * k + 6, 6 * k : 6 * k + 6] = Hpp[k]
        gp = gp.ravel()
        improved = False
        for _try in range(6):
            Hll_d = Hll * (1.0 + lam) + 1e-12
            A = Hpp_full + lam * np.diag(np.diag(Hpp_full)) + 1e-9 * np.eye(P)
            S = A - (Hpl / Hll_d) @ Hpl.T
            rhs = -gp + (Hpl / Hll_d) @ gl
            try:
                dp = np.linalg.solve(S, rhs)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            dl = -(gl + Hpl.T @ dp) / Hll_d
            d = dp.reshape(F - 1, 6)
            Rn, tn = R.copy(), t.copy()
            Rn[1:] = np.stack([cv2.Rodrigues(d[k, :3])[0] for k in range(F - 1)]) @ R[1:]
            tn[1:] = t[1:] + d[:, 3:]
            rhon = np.maximum(rho + dl, 1e-6)
            rn, RXn, Xcn, zn = residuals(Rn, tn, rhon)
            cn = total_cost(rn, rhon)
            if cn < cost:
                R, t, rho, r, RX, Xc, z = Rn, tn, rhon, rn, RXn, Xcn, zn
                improved, step_small = True, cost - cn < 1e-5 * cost
                cost = cn
                lam = max(lam / 10.0, 1e-7)
                break
            lam *= 10.0
        if not improved or step_small:
            break
    out = T_i_0.copy()
    out[:, :3, :3], out[:, :3, 3] = R, t
    out[0] = T_i_0[0]
    return out, rho
