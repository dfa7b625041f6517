"""Flow correspondences (GaussianFlow SLAM): reprojection of source pixels into the target keyframe.

For a keyframe pair (a -> b) with N flow matches ``uv_src -> uv_tgt`` and source depths ``d`` (z, in
the units of variable a's local frame)::

    p_k   = backproject(K, uv_src[k], d[k])                  camera a
    y_k   = T_a(L_a p_k)                                     world
    c_k   = L_b^-1 (T_b^-1 y_k)                              camera b
    e_k   = pi(K, c_k) - uv_tgt[k]                           pixels, [2]
    r_k   = sqrt(c_k * w_k) * e_k / sigma_px                 dimension 2N

``T_a``, ``T_b`` are the variables (Pose3 or Similarity3, e.g. keyframe poses ``T_world_cam`` or
submap transforms ``S_i``); ``L_a``, ``L_b`` are optional fixed rigid local offsets
(``T_world_cam_a = T_a L_a``), identity by default. ``c_k`` is the a-priori weight (e.g. flow
forward-backward consistency) and ``w_k`` the robust weight, recomputed from the current residual at
every linearization (IRLS) from an inlier/outlier mixture: a Gaussian inlier (std ``sigma_px``,
prior ``inlier_prior``) against a uniform outlier over an ``outlier_range_px`` square::

    w_k = p N(e_k; 0, sigma^2 I) / (p N(e_k; 0, sigma^2 I) + (1 - p) / range^2)

The weight is held constant in the Jacobian (as GTSAM's robust noise models do), so an outlier only
loses its own rows instead of down-weighting the whole pair. Points that fall behind camera b get
zero rows. The noise model is ``Unit(2N)``.
"""

from __future__ import annotations

import gtsam
import numpy as np

from ._lie import (
    action_jacobian,
    check_count,
    check_group,
    check_positive,
    check_shape,
    inverse_action_jacobian,
    read_transform,
)
from .errors import FactorInputError

_MIN_Z = 1e-6


def mixture_weights(e: np.ndarray, sigma: float, inlier_prior: float, outlier_range: float) -> np.ndarray:
    """Posterior inlier probability of pixel errors ``e`` [N, 2] -> [N]."""
    q = (e**2).sum(axis=1) / sigma**2
    p_in = inlier_prior * np.exp(-0.5 * q) / (2.0 * np.pi * sigma**2)
    p_out = (1.0 - inlier_prior) / outlier_range**2
    return p_in / (p_in + p_out)


def flow_residual(
    A,
    B,
    X_a: np.ndarray,
    L_b_inv: np.ndarray,
    K: np.ndarray,
    uv_tgt: np.ndarray,
    group: str,
    want_jac: bool = True,
):
    """Unweighted pixel errors -> (e [N, 2], J_A [N, 2, d], J_B [N, 2, d], valid [N]).

    ``X_a`` [N, 3] are the source points already in variable a's local frame (``L_a p``).
    """
    RA, tA, sA = A
    RB, tB, sB = B
    y = X_a @ (sA * RA).T + tA  # world
    z = (y - tB) @ RB / sB  # T_b^-1 y   (row form of R^T (y - t) / s)
    Rl, tl = L_b_inv[:3, :3], L_b_inv[:3, 3]
    c = z @ Rl.T + tl  # camera b
    cz = c[:, 2]
    valid = cz > _MIN_Z
    czs = np.where(valid, cz, 1.0)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    u = fx * c[:, 0] / czs + cx
    v = fy * c[:, 1] / czs + cy
    e = np.stack([u, v], axis=1) - uv_tgt
    e[~valid] = 0.0
    if not want_jac:
        return e, None, None, valid
    N = len(X_a)
    Jpi = np.zeros((N, 2, 3))
    Jpi[:, 0, 0] = fx / czs
    Jpi[:, 0, 2] = -fx * c[:, 0] / czs**2
    Jpi[:, 1, 1] = fy / czs
    Jpi[:, 1, 2] = -fy * c[:, 1] / czs**2
    Jpi[~valid] = 0.0
    Jc_z = Jpi @ Rl  # [N, 2, 3]: d e / d z
    Jz_y = RB.T / sB  # d z / d y
    JA = (Jc_z @ Jz_y) @ action_jacobian(RA, sA, X_a, group)
    JB = Jc_z @ inverse_action_jacobian(z, group)
    return e, JA, JB, valid


def make_flow_factor(
    key_a: int,
    key_b: int,
    uv_src: np.ndarray,  # [N, 2] pixels in frame a
    depth_src: np.ndarray,  # [N] z in frame a (units of variable a)
    uv_tgt: np.ndarray,  # [N, 2] pixels in frame b
    K: np.ndarray,  # [3, 3] intrinsics of both frames (same camera)
    sigma_px: float = 1.0,
    weight: np.ndarray | None = None,  # [N] a-priori weights in [0, 1]
    inlier_prior: float = 0.9,
    outlier_range_px: float = 50.0,
    group: str = "pose3",
    L_a: np.ndarray | None = None,  # [4, 4] rigid, T_world_cam_a = T_a @ L_a
    L_b: np.ndarray | None = None,  # [4, 4] rigid, T_world_cam_b = T_b @ L_b
    robust: bool = True,
) -> gtsam.CustomFactor:
    """Batched flow reprojection factor between two variables, residual dimension 2N."""
    check_group(group)
    uv_src = check_shape("uv_src", uv_src, (None, 2))
    N = len(uv_src)
    uv_tgt = check_shape("uv_tgt", uv_tgt, (N, 2))
    d = check_shape("depth_src", depth_src, (N,))
    K = check_shape("K", K, (3, 3))
    c = np.ones(N) if weight is None else check_shape("weight", weight, (N,))
    check_count("flow factor", N)
    if key_a == key_b:
        raise FactorInputError(
            "a flow factor needs two different variables (pairs inside one submap are fixed)"
        )
    if np.any(d <= 0):
        raise FactorInputError(f"depth_src must be positive, got {int((d <= 0).sum())} non-positive values")
    if np.any(c < 0):
        raise FactorInputError("weight must be non-negative")
    sigma = check_positive("sigma_px", sigma_px)
    if not 0.0 < inlier_prior <= 1.0:
        raise FactorInputError(f"inlier_prior must be in (0, 1], got {inlier_prior}")
    rng = check_positive("outlier_range_px", outlier_range_px)
    La = np.eye(4) if L_a is None else check_shape("L_a", L_a, (4, 4))
    Lb = np.eye(4) if L_b is None else check_shape("L_b", L_b, (4, 4))
    x = (uv_src[:, 0] - K[0, 2]) / K[0, 0]
    y = (uv_src[:, 1] - K[1, 2]) / K[1, 1]
    p = np.stack([x * d, y * d, d], axis=1)
    X_a = np.ascontiguousarray(p @ La[:3, :3].T + La[:3, 3])
    Lb_inv = np.linalg.inv(Lb)
    sqrt_c = np.sqrt(c) / sigma

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H) -> np.ndarray:
        ka, kb = this.keys()
        e, JA, JB, valid = flow_residual(
            read_transform(values, ka, group),
            read_transform(values, kb, group),
            X_a,
            Lb_inv,
            K,
            uv_tgt,
            group,
            H is not None,
        )
        s = sqrt_c * np.sqrt(mixture_weights(e, sigma, inlier_prior, rng)) if robust else sqrt_c
        s = np.where(valid, s, 0.0)
        if H is not None:
            dim = JA.shape[2]
            H[0] = (JA * s[:, None, None]).reshape(-1, dim)
            H[1] = (JB * s[:, None, None]).reshape(-1, dim)
        return (e * s[:, None]).ravel()

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(2 * N), [key_a, key_b], error)


__all__ = ["make_flow_factor", "flow_residual", "mixture_weights"]
