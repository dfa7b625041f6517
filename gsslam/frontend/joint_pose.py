"""A pose from colour flow and depth jointly: the PnP inliers' reprojections stacked with dense ICP.

On keyframe pairs of TUM teddy, PnP on forward-backward-checked flow is better in rotation and
point-to-plane ICP on depth better in translation (docs/results.md, "RGB-D keyframe poses from flow and
depth, session 8"). Both are least-squares problems in the same six unknowns, ``T_tgt_src``, so their
residuals are stacked and solved together by one robust Gauss-Newton,
:func:`gsslam.frontend.icp.icp_point_to_plane` with ``matches``:

- **flow** (the PnP inlier set, ``M`` 3D-2D matches: source points from the source depth, their flow
  targets in the target image)::

      e_m = (pi(K, T p_m) - uv_m) / sigma_px                                   [2] px / px

- **depth** (projective point-to-plane association, source point ``p`` against the target point ``q``
  with normal ``n`` that it lands on)::

      r = n . (T p - q) / sigma(z),   sigma(z) = sigma0 + sigma2 z^2           [1] m / m

Both are Huber-weighted (``huber`` in units of their sigma). The flow term is scaled by ``flow_weight``:
neither term's errors are independent per point (flow of neighbouring pixels shares its DIS patch,
depth its sensor bias), so the plain sum of informations is not the right balance; the weight is
measured (docs/results.md). Perturbation: left, ``T <- exp(xi) T``, ``xi`` = (translation, rotation)
(:func:`gsslam.frontend.icp.reprojection_residuals`, :func:`~gsslam.frontend.icp.point_to_plane_residuals`;
tests compare their Jacobians with numerical derivatives). The depth term is coarse to fine
(``strides``), the flow term the same at every level.

What this module adds to the solver: the flow inliers are chosen once, at the start (the PnP pose), and
the joint solve has no conditioning check (the flow term observes what a plane leaves free).
"""

from __future__ import annotations

import numpy as np

from gsslam.frontend.icp import IcpResult, icp_point_to_plane, reprojection_residuals
from gsslam.types import CameraIntrinsics

JOINT_TOL = 1e-6  # step (m, rad) below which a level stops


def flow_inliers(
    T: np.ndarray, X_src: np.ndarray, uv_tgt: np.ndarray, K: np.ndarray, threshold_px: float
) -> np.ndarray:  # [M] bool: finite matches in front of the camera, reprojected within threshold_px
    ok = np.isfinite(X_src).all(1) & np.isfinite(uv_tgt).all(1)
    e = np.full(len(X_src), np.inf)
    if ok.any():
        Xo = X_src[ok]
        front = (Xo @ T[2, :3] + T[2, 3]) > 1e-6
        ee, _ = reprojection_residuals(T, Xo, uv_tgt[ok], K)
        e[np.flatnonzero(ok)[front]] = np.linalg.norm(ee[front], axis=1)
    return e < threshold_px


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
    **icp_kwargs,  # sigma0, sigma2, huber, max_dist, min_points, max_step_m, max_step_deg
) -> IcpResult:
    """Joint flow + depth pose ``T_tgt_src`` (module docstring); ``matches`` = the flow inliers used. Not
    ok (the start returned) when the depth has too few matches, the system is singular or the result
    moved far from the start."""
    T0 = np.asarray(T_init, dtype=np.float64)
    inl = flow_inliers(T0, X_src, uv_tgt, intr.K, inlier_px)
    X, uv = X_src[inl].astype(np.float64), uv_tgt[inl].astype(np.float64)
    return icp_point_to_plane(
        depth_src, depth_tgt, intr, T0, strides=strides, iterations=iterations, min_condition=0.0,
        matches=(X, uv, intr.K), match_sigma_px=sigma_px, match_weight=flow_weight, tol=JOINT_TOL,
        **icp_kwargs,
    )  # fmt: skip
