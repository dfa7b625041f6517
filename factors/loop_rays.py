"""Loop points with a depth-aware noise: along the viewing ray and across it (mono loops).

A mono point map is accurate across the viewing ray (the pixel) and poor along it (the depth). The
same physical points, known in the local frames of Sim(3) variables ``S_a`` and ``S_b``, are compared
in ``a``'s local frame and units::

    d_k = X_a[k] - (S_a^-1 S_b) X_b[k]                     k = 1..N
    r_k = W_k d_k,   W_k = I / sigma_perp + (1 / sigma_ray - 1 / sigma_perp) u_k u_k^T

with ``u_k = X_a[k] / |X_a[k]|`` the ray of the point from ``a``'s origin (its first keyframe; a
submap's keyframes are close to it against the scene depth). Dimension 3N, units of submap ``a``:
invariant to any Sim(3) applied to the whole world, so neither the chain's scale nor its pose can
satisfy it. With ``sigma_ray == sigma_perp`` it is :mod:`loop_points`' residual expressed in ``a``'s axes.

``dcs_phi > 0``: the factor's noise model is robust, dynamic covariance scaling (DCS, Agarwal et al.
2013) on the loop's whole chi-square with ``Phi = dcs_phi x 3N``: a loop that the graph meets within
its own noise (chi-square about ``3N`` when the sigmas are the loop's residual statistics) keeps its
full weight; beyond ``Phi`` its weight falls as ``(2 Phi / (Phi + chi2))^2``.

Jacobians in the right-perturbation chart (rotation, translation, log-scale), ``Y = (S_a^-1 S_b) X_b``,
``s R`` the linear part of ``S_a^-1 S_b``: ``dd/dxi_a = [-[Y]x, I, Y]``,
``dd/dxi_b = -s R [-[X_b]x, I, X_b]``; both times ``W_k``. Similarity3 only. Noise model ``Unit(3N)``
(or ``Robust(DCS, Unit(3N))``, below).
"""

from __future__ import annotations

import gtsam
import numpy as np

from ._lie import sim3_pair_factor, skew_batch
from .errors import FactorInputError
from .points import checked_point_pair


def ray_whitening(X_a: np.ndarray, sigma_ray: np.ndarray, sigma_perp: np.ndarray) -> np.ndarray:
    """``W_k`` [N, 3, 3] for points ``X_a`` [N, 3] (rays from the origin), sigmas [N]."""
    u = X_a / np.linalg.norm(X_a, axis=1, keepdims=True)  # [N, 3]
    uu = u[:, :, None] * u[:, None, :]
    return np.eye(3)[None] / sigma_perp[:, None, None] + (1 / sigma_ray - 1 / sigma_perp)[:, None, None] * uu


def ray_point_residual(A, B, X_a: np.ndarray, X_b: np.ndarray, W: np.ndarray, want_jac: bool = True):
    """(R, t, s) of both Sim(3) variables -> (r [3N], J_A [3N, 7], J_B [3N, 7]); ``W`` [N, 3, 3]."""
    RA, tA, sA = A
    RB, tB, sB = B
    s_ab, R_ab = sB / sA, RA.T @ RB
    t_ab = RA.T @ (tB - tA) / sA
    Y = s_ab * X_b @ R_ab.T + t_ab  # [N, 3]
    r = np.einsum("nij,nj->ni", W, X_a - Y)
    if not want_jac:
        return r.ravel(), None, None
    n = len(X_a)
    eye = np.broadcast_to(np.eye(3), (n, 3, 3))
    Ja = np.concatenate([-skew_batch(Y), eye, Y[:, :, None]], axis=2)  # [N, 3, 7]
    Jb = np.concatenate([-skew_batch(X_b), eye, X_b[:, :, None]], axis=2)
    Jb = -s_ab * np.einsum("ij,njk->nik", R_ab, Jb)
    JA = np.einsum("nij,njk->nik", W, Ja).reshape(-1, 7)
    return r.ravel(), JA, np.einsum("nij,njk->nik", W, Jb).reshape(-1, 7)


def make_ray_point_factor(
    key_a: int,
    key_b: int,
    X_a: np.ndarray,  # [N, 3] in key_a's local frame
    X_b: np.ndarray,  # [N, 3] in key_b's local frame
    sigma_ray: float | np.ndarray,  # scalar or [N], key_a's local units, along the ray
    sigma_perp: float | np.ndarray,  # scalar or [N], key_a's local units, across it (per axis)
    dcs_phi: float = 0.0,  # > 0: DCS kernel with Phi = dcs_phi x 3N (0: Gaussian)
) -> gtsam.CustomFactor:
    """Batched loop-point factor between two Similarity3 variables, depth-aware, in key_a's units (3N)."""
    X_a, X_b, w_ray = checked_point_pair("ray point factor", key_a, key_b, X_a, X_b, sigma_ray)
    _, _, w_perp = checked_point_pair("ray point factor", key_a, key_b, X_a, X_b, sigma_perp)
    if np.any(np.linalg.norm(X_a, axis=1) < 1e-12):
        raise FactorInputError("ray point factor: a point of X_a at its frame's origin has no ray")
    if not (np.isfinite(dcs_phi) and dcs_phi >= 0):
        raise FactorInputError(f"ray point factor: dcs_phi must be >= 0, got {dcs_phi}")
    W = ray_whitening(X_a, 1.0 / w_ray, 1.0 / w_perp)
    noise = gtsam.noiseModel.Unit.Create(3 * len(X_a))
    if dcs_phi > 0:
        dcs = gtsam.noiseModel.mEstimator.DCS.Create(dcs_phi * 3 * len(X_a))
        noise = gtsam.noiseModel.Robust.Create(dcs, noise)

    return sim3_pair_factor(noise, key_a, key_b, lambda A, B, jac: ray_point_residual(A, B, X_a, X_b, W, jac))


__all__ = ["make_ray_point_factor", "ray_point_residual", "ray_whitening"]
