"""Camera pose from 3D-2D matches (PnP RANSAC + Levenberg-Marquardt refinement) and flow sampling.

The one PnP of the frontend: the RGB-D and monocular encoders and frame tracking
(:func:`gsslam.frontend.tracking.solve_relative_pose`) all call :func:`pnp`. Poses are ``T_tgt_src``:
they map points of the source camera (where the 3D points live) into the target camera (where the
pixels are).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np

from gsslam.geometry import backproject, so3_log

log = logging.getLogger(__name__)


@dataclass
class PnPResult:
    T_tgt_src: np.ndarray | None  # [4, 4] or None when PnP failed
    inliers: int
    rms_px: float  # reprojection RMS over the inliers after refinement


def pnp(
    X_src: np.ndarray,  # [N, 3] points in the source camera
    uv_tgt: np.ndarray,  # [N, 2] their pixels in the target image
    K: np.ndarray,  # [3, 3] target intrinsics
    threshold_px: float,
    min_inliers: int,
    init: np.ndarray | None = None,  # [4, 4] T_tgt_src guess
    iterations: int = 200,
    min_inlier_ratio: float = 0.0,
    reselect: bool = True,
) -> PnPResult:
    """RANSAC EPnP (or iterative from ``init``), then LM refinement on the inliers.

    Fails (``T_tgt_src=None``) with fewer than ``min_inliers`` RANSAC inliers or a smaller share than
    ``min_inlier_ratio`` of the usable points. ``reselect``: after the first refinement, take the points
    within ``threshold_px`` of the refined pose as inliers and refine once more.
    """
    ok_pts = np.isfinite(X_src).all(1) & np.isfinite(uv_tgt).all(1) & (X_src[:, 2] > 0)
    X, uv = X_src[ok_pts].astype(np.float64), uv_tgt[ok_pts].astype(np.float64)
    if len(X) < max(6, min_inliers):
        return PnPResult(None, 0, float("nan"))
    use_guess = init is not None
    rvec0 = cv2.Rodrigues(init[:3, :3])[0] if use_guess else None
    tvec0 = init[:3, 3].reshape(3, 1).copy() if use_guess else None
    try:
        ok, rvec, tvec, inl = cv2.solvePnPRansac(
            X,
            uv,
            K,
            None,
            rvec0,
            tvec0,
            useExtrinsicGuess=use_guess,
            iterationsCount=iterations,
            reprojectionError=threshold_px,
            confidence=0.999,
            flags=cv2.SOLVEPNP_ITERATIVE if use_guess else cv2.SOLVEPNP_EPNP,
        )
    except cv2.error as e:
        log.debug("solvePnPRansac failed: %s", e)
        return PnPResult(None, 0, float("nan"))
    n_in = 0 if inl is None else len(inl)
    if not ok or n_in < min_inliers or n_in < min_inlier_ratio * len(X):
        return PnPResult(None, n_in, float("nan"))
    idx = inl.reshape(-1)
    rvec, tvec = cv2.solvePnPRefineLM(X[idx], uv[idx], K, None, rvec, tvec)
    if reselect:  # re-select inliers with the refined pose and refine once more
        proj = cv2.projectPoints(X, rvec, tvec, K, None)[0].reshape(-1, 2)
        err = np.linalg.norm(proj - uv, axis=1)
        idx = np.flatnonzero(err < threshold_px)
        if len(idx) < min_inliers:
            return PnPResult(None, len(idx), float("nan"))
        rvec, tvec = cv2.solvePnPRefineLM(X[idx], uv[idx], K, None, rvec, tvec)
    proj = cv2.projectPoints(X[idx], rvec, tvec, K, None)[0].reshape(-1, 2)
    rms = float(np.sqrt(np.mean(np.sum((proj - uv[idx]) ** 2, axis=1))))
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(rvec)[0]
    T[:3, 3] = tvec.reshape(3)
    return PnPResult(T, len(idx), rms)


def random_flow_matches(
    flow: np.ndarray,  # [h, w, 2] source -> target
    valid: np.ndarray,  # [h, w] bool
    depth_src: np.ndarray | None,  # [h, w] or None
    max_points: int,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Up to ``max_points`` random valid pixels (with finite positive depth when given) and their flow
    targets: uv_src, uv_tgt [N, 2], z [N] (NaN without depth). Frame tracking samples a regular grid
    instead (:func:`gsslam.frontend.tracking.grid_flow_matches`)."""
    h, w = flow.shape[:2]
    ok = valid & np.isfinite(flow).all(-1)
    if depth_src is not None:
        with np.errstate(invalid="ignore"):
            ok &= np.isfinite(depth_src) & (depth_src > 0)
    idx = np.flatnonzero(ok.reshape(-1))
    if len(idx) > max_points:
        idx = rng.choice(idx, max_points, replace=False)
    v, u = np.divmod(idx, w)
    uv_src = np.stack([u, v], 1).astype(np.float64)
    uv_tgt = uv_src + flow.reshape(-1, 2)[idx]
    z = depth_src.reshape(-1)[idx].astype(np.float64) if depth_src is not None else np.full(len(idx), np.nan)
    return uv_src, uv_tgt, z


def pnp_from_flow(
    depth_src: np.ndarray,  # [h, w] source depth
    flow: np.ndarray,  # [h, w, 2] source -> target
    valid: np.ndarray,  # [h, w] bool
    K: np.ndarray,  # [3, 3] (same for both frames)
    threshold_px: float,
    min_inliers: int,
    rng: np.random.Generator,
    max_points: int = 3000,
    init: np.ndarray | None = None,
) -> PnPResult:
    uv_s, uv_t, z = random_flow_matches(flow, valid, depth_src, max_points, rng)
    return pnp(backproject(K, uv_s, z), uv_t, K, threshold_px, min_inliers, init)


def pose_distance(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """(translation difference, rotation difference in degrees) between two rigid poses."""
    D = np.linalg.inv(T_a) @ T_b
    return float(np.linalg.norm(D[:3, 3])), float(np.degrees(np.linalg.norm(so3_log(D[:3, :3]))))
