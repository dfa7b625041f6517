"""The depth-to-colour baseline from the two cameras' motions: hand-eye calibration (session 15).

The depth camera sits at ``b_vec = (b, 0, 0)`` in the colour camera's frame, so over a frame pair the colour
camera's motion is the depth camera's conjugated by that offset::

    T_colour = Tb T_depth Tb^-1   ->   R equal,   t_colour = t_depth + (I - R) b_vec

A turn of ``theta`` about an axis across x separates the two translations by ``theta b`` (~1 mm for 2 deg and
25 mm): ``b`` is observed through a millimetre, and only as well as both motions are known along that
direction (mostly the optical axis for a pan).

- The colour camera's motion from the flow alone (each flow pixel's point from the depth image, moved, seen
  from the colour camera; iteratively reweighted Gauss-Newton on the truncated reprojection error) and its 6x6
  covariance. Thousands of flow vectors fix it to ~0.1 mm and 0.005 deg on the Kinect room.
- The depth camera's motion from point-to-plane ICP of the depth images with the target's normals from
  depth smoothed by a Gaussian (``SMOOTH_PX``), and its 6x6 covariance. Smoothed normals do not condition a
  direction the geometry leaves free: on the room's bare walls ICP slides 6-100 mm along the wall, and the
  covariance says so (a few mm there, ~0.2 mm along the depth axis).
- ``b``: the weighted least squares of the 6-vector ``log(T_colour (Tb T_depth Tb^-1)^-1)`` (linear in ``b``)
  over the pairs, each weighted by the inverse of the two motions' summed covariance, so that a slide along
  a wall, and its correlation with the depth axis, count as what they are. The points read from the depth
  image depend on ``b`` a little: solved again at the new ``b`` (``rounds``).
- The pairs must agree with the model: the median over pairs of ``w_i (b_i - b)^2`` (each pair's own
  baseline's squared deviation in its own standard deviations) at most ``MAX_MEDIAN_CHI2``, else
  ``consistent`` is False and the caller keeps its own estimate. Measured (docs/results.md, session 15):
  2.1-2.5 on the synthetic Kinect room's first window (ray-cast / splat); 74-115 on the TUM teddy
  playbacks, whose colour and depth motions disagree by millimetres beyond any baseline (real data; the
  cause is not known: the colour camera's rolling shutter, the two streams' exposures or the real depth's
  own distortion).

The fixed-motion fit of :mod:`gsslam.frontend.depth_registration` instead holds ICP's whole motion and fits
``b`` to the flow's residual: a 1 mm ICP error moves it by ~30 mm (docs/results.md, sessions 13-15).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gsslam.frontend.colour_focal import TRUNCATE_PX, FlowPair, depth_camera_points
from gsslam.frontend.icp import grid_normals, reprojection_residuals, strided_points
from gsslam.frontend.registration_joint import plane_matches, smoothed_depth
from gsslam.geometry import so3_exp, so3_log
from gsslam.types import CameraIntrinsics

SMOOTH_PX = 3.0  # Gaussian sigma of the target depth behind the ICP normals and covariance
ICP_POINTS_SIDE = 160  # the ICP samples the depth image at about this many points across (stride 2 at 320 px)
WIDE_TRUNCATE_PX = 40.0  # the flow fit's first iterations truncate here (ICP's start can be millimetres off)
MAX_MEDIAN_CHI2 = 25.0  # the pairs' median squared deviation (in their own sigmas) beyond which b is not used


@dataclass(frozen=True)
class HandEyeBaseline:
    baseline_m: float  # the pooled baseline (NaN: no pair observes it)
    pair_baselines_m: tuple[float, ...]  # each pair's own (NaN where its rotation does not observe b)
    pair_weights: tuple[float, ...]  # each pair's information on b (1 / m^2)
    std_m: float  # the pooled estimate's standard deviation from those weights
    median_chi2: float  # the median over pairs of weight * (own - pooled)^2

    @property
    def consistent(self) -> bool:
        return bool(np.isfinite(self.baseline_m) and self.median_chi2 <= MAX_MEDIAN_CHI2)


def _exp_left(step: np.ndarray, T: np.ndarray) -> np.ndarray:  # [6] (translation, rotation), [4, 4]
    dT = np.eye(4)
    dT[:3, :3] = so3_exp(step[3:])
    dT[:3, 3] = step[:3]
    return dT @ T


def colour_motion(
    pair: FlowPair,
    colour: CameraIntrinsics,
    f_depth: tuple[float, float],  # (fx, fy) of the depth camera
    baseline_m: float,
    T_init: np.ndarray,  # [4, 4] colour camera motion to start from
    iterations: int = 12,
) -> tuple[np.ndarray, np.ndarray] | None:  # T_b_a colour camera [4, 4], its covariance [6, 6] (left)
    """The colour camera's motion from the pair's flow (module doc); None with too few flow points."""
    X, ok = depth_camera_points(pair, colour, f_depth, baseline_m)
    X = X[ok] + np.array([baseline_m, 0.0, 0.0])  # colour camera frame a
    uv = pair.uv_b[ok]
    if len(X) < 30:
        return None
    T = np.asarray(T_init, np.float64).copy()
    for it in range(iterations):
        e, J = reprojection_residuals(T, X, uv, colour.K)
        en = np.linalg.norm(e, axis=1)
        wt = (en < (TRUNCATE_PX if it >= iterations // 2 else WIDE_TRUNCATE_PX)) / np.maximum(en, 0.25)
        Jw = J * wt[:, None, None]
        H = np.einsum("mki,mkj->ij", Jw, J)
        g = np.einsum("mki,mk->i", Jw, e)
        T = _exp_left(-np.linalg.solve(H + 1e-9 * np.eye(6), g), T)
    if wt.sum() <= 0:
        return None
    s2 = float(np.sum(wt * en**2) / wt.sum())  # the residuals' scale (px^2)
    return T, np.linalg.inv(H + 1e-9 * np.eye(6)) * s2


def depth_motion(
    depth_a: np.ndarray,  # [H, W] metres, NaN invalid (depth camera)
    depth_b: np.ndarray,  # [H, W]
    intr: CameraIntrinsics,  # the depth camera's
    T_init: np.ndarray,  # [4, 4] T_b_a to start from (the pair's ICP motion)
    iterations: int = 20,
    sigma0: float = 0.002,
    sigma2: float = 0.002,
    max_dist: float = 0.05,
    huber: float = 2.0,
) -> tuple[np.ndarray, np.ndarray] | None:  # T_b_a [4, 4] (depth camera), its covariance [6, 6] (left)
    """Point-to-plane ICP, the target's normals from smoothed depth (module doc); None: too few matches."""
    stride = max(1, round(depth_a.shape[1] / ICP_POINTS_SIDE))
    Ps, _ = strided_points(np.asarray(depth_a, np.float64), intr, stride)
    Pt, Kt = strided_points(smoothed_depth(depth_b, SMOOTH_PX), intr, stride)
    Nt = grid_normals(Pt)
    src = Ps.reshape(-1, 3)
    src = src[np.isfinite(src).all(1)]
    T = np.asarray(T_init, np.float64).copy()
    for _ in range(iterations):
        p, q, n = plane_matches(src, T, Pt, Nt, Kt, max_dist)
        if len(p) < 300:
            return None
        sig = sigma0 + sigma2 * q[:, 2] ** 2
        r = np.einsum("ij,ij->i", n, p - q) / sig
        wt = np.minimum(1.0, huber / np.maximum(np.abs(r), 1e-12))
        J = np.concatenate([n, np.cross(p, n)], 1) / sig[:, None]
        H = (J * wt[:, None]).T @ J + 1e-9 * np.eye(6)
        step = -np.linalg.solve(H, (J * wt[:, None]).T @ r)
        T = _exp_left(step, T)
        if np.linalg.norm(step) < 1e-7:
            break
    s2 = float(np.sum(wt * r**2) / max(wt.sum(), 1e-12))  # the residuals' scale (in sigmas^2)
    return T, np.linalg.inv(H) * s2


def pair_residual(
    Tc: np.ndarray,  # [4, 4] colour camera motion
    Cc: np.ndarray,  # [6, 6] its covariance
    Td: np.ndarray,  # [4, 4] depth camera motion
    Cd: np.ndarray,  # [6, 6] its covariance
    b: float,  # the baseline at which the residual is taken
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # r0 [6], a [6] (r(b + db) = r0 - a db), W [6, 6]
    """``log(Tc (Tb Td Tb^-1)^-1)`` (translation, rotation), its derivative in ``b`` and its information."""
    Tb = np.eye(4)
    Tb[0, 3] = b
    Tdc = Tb @ Td @ np.linalg.inv(Tb)
    dR = Tc[:3, :3] @ Tdc[:3, :3].T
    r0 = np.concatenate([Tc[:3, 3] - dR @ Tdc[:3, 3], so3_log(dR)])
    a = np.concatenate([dR @ (np.eye(3) - Td[:3, :3]) @ np.array([1.0, 0.0, 0.0]), np.zeros(3)])
    Ad = np.eye(6)  # a left step of Td is a left step of Tb Td Tb^-1 through Tb's adjoint
    Ad[:3, 3:] = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -b], [0.0, b, 0.0]])
    return r0, a, np.linalg.inv(Cc + Ad @ Cd @ Ad.T)


def handeye_baseline(
    pairs: list[FlowPair],
    motions: list[np.ndarray],  # [4, 4] each pair's ICP motion (depth camera) at the registration's k
    colour: CameraIntrinsics,  # the colour camera's intrinsics at that k
    depth: CameraIntrinsics,  # the depth camera's
    baseline_m: float,  # where to start (the fixed-motion fit's)
    rounds: int = 2,
) -> HandEyeBaseline:
    """The baseline from each pair's colour motion (flow) and depth motion (ICP) (module doc)."""
    b = float(baseline_m)
    depth_motions = [depth_motion(p.raw_a, p.raw_b, depth, T) for p, T in zip(pairs, motions)]
    res = HandEyeBaseline(float("nan"), (), (), float("nan"), float("nan"))
    for _ in range(rounds):
        rows = []  # (b_i, weight_i) per pair that gives both motions
        for p, T, dm in zip(pairs, motions, depth_motions):
            Tb = np.eye(4)
            Tb[0, 3] = b
            cm = colour_motion(p, colour, (depth.fx, depth.fy), b, Tb @ T @ np.linalg.inv(Tb))
            if cm is None or dm is None:
                continue
            try:
                r0, a, W = pair_residual(cm[0], cm[1], dm[0], dm[1], b)
            except np.linalg.LinAlgError:
                continue
            info = float(a @ W @ a)
            if info > 0:
                rows.append((b + float(a @ W @ r0) / info, info))
        if not rows:
            return res
        own, wts = np.array([r[0] for r in rows]), np.array([r[1] for r in rows])
        b = float(np.sum(wts * own) / wts.sum())
        chi2 = float(np.median(wts * (own - b) ** 2))
        res = HandEyeBaseline(b, tuple(round(float(x), 5) for x in own), tuple(wts.tolist()),
                              float(1.0 / np.sqrt(wts.sum())), chi2)  # fmt: skip
    return res
