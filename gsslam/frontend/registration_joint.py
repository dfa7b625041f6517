"""The depth-to-colour baseline from each pair's motion re-solved with its flow (session 14).

:mod:`gsslam.frontend.depth_registration` fits the baseline ``b`` with each pair's depth-camera motion held
at its ICP estimate. A turn of ``theta`` moves the colour camera by only ``theta b`` (~1 mm for 2 deg and
25 mm) relative to the depth camera, so the flow observes ``b`` through a ~0.02 px effect, and an ICP
translation error of a millimetre moves the fit by centimetres. On bare walls ICP slides 6-9 mm along the
wall although its normal matrix (of noisy Kinect normals) calls the direction observed (docs/results.md,
"The registration baseline under Kinect noise, session 13").

Here each pair's motion ``T`` (depth camera, ``T_b_a``) is free, held to its ICP estimate ``T0`` only by
the information the depth geometry has, and fitted to the flow at every candidate ``b``; ``b`` is the
median of the pairs' minima of::

    cost(b) = sum_pairs min_T [ sum_m min(|e_m(T, b)|, 4 px)  +  w/2 xi^T H xi ],   T = exp(xi) T0

- ``e_m``: the flow residual of :func:`gsslam.frontend.colour_focal.reprojection_cost` (px; the colour
  pixel's point from the depth image at ``b``, moved by ``T``, seen from the colour camera);
- ``H``: the point-to-plane normal matrix at ``T0`` (left perturbation, translation then rotation) with
  normals of the depth images smoothed by a Gaussian (``SMOOTH_PX``), so that sensor noise does not
  condition a direction the geometry leaves free (a wall's own plane); ``w`` its weight (``weight``).

Where the depth geometry observes the motion the prior keeps ICP's; where it does not, the flow sets it
and that direction says nothing about ``b``. ``w`` large: the fixed-motion fit; ``w`` 0: motion from the
flow alone (``b`` then only from the scene's relief). Solved per pair and ``b`` by iteratively reweighted
Gauss-Newton (the truncated L1 cost as weights ``1 / max(|e|, 0.25 px)`` inside 4 px).
"""

from __future__ import annotations

import cv2
import numpy as np

from gsslam.frontend.colour_focal import TRUNCATE_PX, FlowPair, depth_camera_points, parabola_min
from gsslam.frontend.icp import grid_normals, reprojection_residuals, strided_points
from gsslam.geometry import so3_exp, so3_log
from gsslam.types import CameraIntrinsics

SMOOTH_PX = 3.0  # Gaussian sigma of the depth smoothing for the prior's normals
PRIOR_STRIDE = 4  # depth pixels sampled for the prior's normal matrix
BASELINES_M = np.arange(-0.03, 0.1001, 0.0025)  # the profile's grid
ITERATIONS = 6
IRLS_FLOOR_PX = 0.25
FIT_HALF_WIDTH_M = 0.0075  # the minimum: a parabola fitted over the profile this far either side of its lowest


def smoothed_depth(depth: np.ndarray, sigma_px: float) -> np.ndarray:  # [H, W] -> [H, W] float64, NaN holes
    """Normalised Gaussian smoothing of valid depth (holes stay holes)."""
    d = np.nan_to_num(np.asarray(depth, np.float64), nan=0.0)
    m = (d > 0).astype(np.float64)
    k = int(2 * round(3 * sigma_px) + 1)
    num = cv2.GaussianBlur(d, (k, k), sigma_px)
    den = cv2.GaussianBlur(m, (k, k), sigma_px)
    return np.where((den > 0.5) & (m > 0), num / np.maximum(den, 1e-9), np.nan)


def plane_matches(
    src: np.ndarray,  # [M, 3] finite source points (depth camera a)
    T_b_a: np.ndarray,  # [4, 4] the motion they are moved by
    Pt: np.ndarray,  # [h, w, 3] target grid points (NaN holes)
    Nt: np.ndarray,  # [h, w, 3] their normals
    Kt: np.ndarray,  # [3, 3] the grid's intrinsics
    max_dist: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # moved points, matched points, normals [N, 3] each
    """Projective association: each moved point in front of the camera with the target grid point it
    projects onto, kept where that point and its normal exist and lie within ``max_dist``."""
    p = src @ T_b_a[:3, :3].T + T_b_a[:3, 3]
    p = p[p[:, 2] > 0.1]
    h, w = Pt.shape[:2]
    u = np.rint(Kt[0, 0] * p[:, 0] / p[:, 2] + Kt[0, 2]).astype(int)
    v = np.rint(Kt[1, 1] * p[:, 1] / p[:, 2] + Kt[1, 2]).astype(int)
    ins = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    q, n, p = Pt[v[ins], u[ins]], Nt[v[ins], u[ins]], p[ins]
    good = np.isfinite(q).all(1) & np.isfinite(n).all(1)
    good[good] = np.linalg.norm(p[good] - q[good], axis=1) < max_dist
    return p[good], q[good], n[good]


def depth_information(
    depth_a: np.ndarray,  # [H, W] metres, NaN invalid (depth camera)
    depth_b: np.ndarray,  # [H, W]
    intr: CameraIntrinsics,  # the depth camera's
    T_b_a: np.ndarray,  # [4, 4] the motion at which it is taken
    sigma0: float = 0.002,
    sigma2: float = 0.002,
    max_dist: float = 0.05,
) -> np.ndarray:  # [6, 6] point-to-plane normal matrix (left perturbation of T_b_a; translation, rotation)
    """What the depth geometry says about the motion: the point-to-plane normal matrix, smoothed normals."""
    Ps, _ = strided_points(smoothed_depth(depth_a, SMOOTH_PX), intr, PRIOR_STRIDE)
    Pt, Kt = strided_points(smoothed_depth(depth_b, SMOOTH_PX), intr, PRIOR_STRIDE)
    Nt = grid_normals(Pt)
    src = Ps.reshape(-1, 3)
    p, q, n = plane_matches(src[np.isfinite(src).all(1)], T_b_a, Pt, Nt, Kt, max_dist)
    J = np.concatenate([n, np.cross(p, n)], 1) / (sigma0 + sigma2 * q[:, 2:3] ** 2)
    return J.T @ J


def _xi(T: np.ndarray, T0: np.ndarray) -> np.ndarray:  # [6] T = exp(xi) T0, to first order
    dR = T[:3, :3] @ T0[:3, :3].T
    return np.concatenate([T[:3, 3] - dR @ T0[:3, 3], so3_log(dR)])


def pair_profile(
    pair: FlowPair,
    T0: np.ndarray,  # [4, 4] the pair's ICP motion (depth camera)
    H: np.ndarray,  # [6, 6] depth_information at T0
    colour: CameraIntrinsics,
    f_depth: tuple[float, float],
    baselines: np.ndarray,  # [B] metres
    weight: float,
) -> np.ndarray:  # [B] the pair's cost at each baseline, its motion re-solved (module doc)
    K = colour.K
    out = np.empty(len(baselines))
    for j, b in enumerate(baselines):
        X, ok = depth_camera_points(pair, colour, f_depth, float(b))
        X, uv = X[ok], pair.uv_b[ok]
        Tb = np.eye(4)
        Tb[0, 3] = b
        A = np.eye(6)  # adjoint of Tb: a left step of T is a left step of Tb T
        A[:3, 3:] = np.array([[0, 0, 0], [0, 0, -b], [0, b, 0]])
        T = np.asarray(T0, np.float64).copy()
        for _ in range(ITERATIONS):
            e, J = reprojection_residuals(Tb @ T, X, uv, K)
            J = J @ A
            en = np.linalg.norm(e, axis=1)
            wt = (en < TRUNCATE_PX) / np.maximum(en, IRLS_FLOOR_PX)
            Jw = J * wt[:, None, None]
            xi = _xi(T, T0)
            Hs = np.einsum("mki,mkj->ij", Jw, J) + weight * H
            g = np.einsum("mki,mk->i", Jw, e) + weight * H @ xi
            try:
                step = -np.linalg.solve(Hs + 1e-9 * np.eye(6), g)
            except np.linalg.LinAlgError:
                break
            dT = np.eye(4)
            dT[:3, :3] = so3_exp(step[3:])
            dT[:3, 3] = step[:3]
            T = dT @ T
        e, _ = reprojection_residuals(Tb @ T, X, uv, K)
        xi = _xi(T, T0)
        out[j] = np.minimum(np.linalg.norm(e, axis=1), TRUNCATE_PX).sum() + 0.5 * weight * xi @ H @ xi
    return out


def joint_baseline(
    pairs: list[FlowPair],
    motions: list[np.ndarray],  # [4, 4] each pair's ICP motion (depth camera) at the registration's k
    colour: CameraIntrinsics,  # the colour camera's intrinsics at that k
    depth: CameraIntrinsics,  # the depth camera's
    weight: float,
    baselines: np.ndarray = BASELINES_M,
) -> tuple[float, tuple[float, ...]]:  # (the pooled baseline, each pair's alone), metres
    """The median of the pairs' own minima of the profile (module doc), and those minima.

    The median, not the minimum of the summed profile: a pair whose ICP motion is grossly wrong in a
    direction the smoothed depth still observes (measured: 47 mm along a wall) keeps a steep profile
    far from the others' and would set the sum's minimum alone (73 mm for 36 on the room's window)."""
    costs = np.array([
        pair_profile(p, T, depth_information(p.raw_a, p.raw_b, depth, T), colour, (depth.fx, depth.fy),
                     baselines, weight)
        for p, T in zip(pairs, motions)
    ])  # fmt: skip
    alone = tuple(round(profile_min(baselines, c), 5) for c in costs)
    return float(np.median(alone)), alone


def profile_min(xs: np.ndarray, cs: np.ndarray, half_width: float = FIT_HALF_WIDTH_M) -> float:
    """The minimum of a profile on the grid ``xs``: the vertex of the least-squares parabola over the points
    within ``half_width`` of the lowest one (nearest-pixel depth reads make the profile bumpy at the grid's
    scale; a three-point parabola follows the bumps). The lowest grid point when the fit has no minimum
    inside that window."""
    j = int(np.argmin(cs))
    near = np.abs(xs - xs[j]) <= half_width + 1e-12
    if near.sum() >= 3:
        a, b, _ = np.polyfit(xs[near] - xs[j], cs[near], 2)
        if a > 0 and abs(-b / (2 * a)) <= half_width:
            return float(xs[j] - b / (2 * a))
    return float(parabola_min(xs, cs)[0])
