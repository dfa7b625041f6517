"""Point coincidence between two submaps: SING3R adjacency points and loop points.

The same physical points, known in two local frames, must land on the same world point::

    r_k = (T_a(X_a[k]) - T_b(X_b[k])) / sigma_k        k = 1..N,  dimension 3N

``X_a``, ``X_b`` [N, 3] are in the local frames (and units) of the variables ``key_a`` / ``key_b``
(Pose3 or Similarity3); the unwhitened residual is in world units. Used for

- adjacency: the shared frame's point maps ``S_{i-1}(X_{i-1,K}) - S_i(X_{i,0})``;
- loops: matched points of a loop submap pair ``S_i(X_i) - S_m(X_m)``.

Jacobian of ``T(x)`` in the right-perturbation chart: ``[-s R [x]x, s R, s R x]`` (the last column
only for Similarity3). One factor holds all N points (vectorized); it is whitened inside, so its
noise model is ``Unit(3N)``.
"""

from __future__ import annotations

import gtsam
import numpy as np

from ._lie import (
    action_jacobian,
    check_count,
    check_group,
    check_shape,
    fill,
    read_transform,
)
from .errors import FactorInputError


def point_residual(A, B, X_a: np.ndarray, X_b: np.ndarray, w: np.ndarray, group: str, want_jac: bool = True):
    """(R, t, s) of both variables -> (r [3N], J_A [3N, d], J_B [3N, d]); ``w`` [N] = 1 / sigma."""
    RA, tA, sA = A
    RB, tB, sB = B
    r = ((X_a @ (sA * RA).T + tA) - (X_b @ (sB * RB).T + tB)) * w[:, None]
    if not want_jac:
        return r.ravel(), None, None
    JA = action_jacobian(RA, sA, X_a, group) * w[:, None, None]
    JB = -action_jacobian(RB, sB, X_b, group) * w[:, None, None]
    d = JA.shape[2]
    return r.ravel(), JA.reshape(-1, d), JB.reshape(-1, d)


def checked_point_pair(name: str, key_a: int, key_b: int, X_a, X_b, sigma):
    """Validate a point factor's inputs -> (X_a, X_b contiguous [N, 3], w [N] = 1 / sigma)."""
    X_a = check_shape("X_a", X_a, (None, 3))
    X_b = check_shape("X_b", X_b, (None, 3))
    if X_a.shape != X_b.shape:
        raise FactorInputError(f"X_a and X_b must have the same shape, got {X_a.shape} and {X_b.shape}")
    check_count(name, len(X_a))
    if key_a == key_b:
        raise FactorInputError("a point factor needs two different variables")
    sig = np.broadcast_to(np.asarray(sigma, dtype=np.float64), (len(X_a),)).copy()
    if not np.all(np.isfinite(sig) & (sig > 0)):
        raise FactorInputError("sigma must be positive and finite (a scalar or one value per point)")
    return np.ascontiguousarray(X_a), np.ascontiguousarray(X_b), 1.0 / sig


def make_point_factor(
    key_a: int,
    key_b: int,
    X_a: np.ndarray,  # [N, 3] in key_a's local frame
    X_b: np.ndarray,  # [N, 3] in key_b's local frame
    sigma: float | np.ndarray,  # scalar or [N], world units
    group: str = "sim3",
) -> gtsam.CustomFactor:
    """Batched point-coincidence factor (adjacency or loop points), residual dimension 3N."""
    check_group(group)
    X_a, X_b, w = checked_point_pair("point factor", key_a, key_b, X_a, X_b, sigma)

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H) -> np.ndarray:
        ka, kb = this.keys()
        r, JA, JB = point_residual(
            read_transform(values, ka, group),
            read_transform(values, kb, group),
            X_a,
            X_b,
            w,
            group,
            H is not None,
        )
        fill(H, 0, JA)
        fill(H, 1, JB)
        return r

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(3 * len(X_a)), [key_a, key_b], error)


__all__ = ["checked_point_pair", "make_point_factor", "point_residual"]
