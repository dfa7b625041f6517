"""Loop points measured in the loop submap's own units (mono): a Sim(3) point factor that cannot be
satisfied by shrinking the world.

The same physical points, known in the local frames of Sim(3) variables ``S_a`` and ``S_b``::

    r_k = (S_a(X_a[k]) - S_b(X_b[k])) / (s_a sigma_k)        k = 1..N,  dimension 3N

i.e. :mod:`points`' residual divided by the scale ``s_a`` of ``S_a``: the misalignment in submap-a units
(rotated into the world's axes), and ``sigma`` in submap-a units. The world-unit residual of
:func:`make_point_factor` shrinks with the submaps' scales, so a strong loop of that kind pulls the
chain's scale down (every world-unit residual shrinks with it); this one does not.

Jacobian in the right-perturbation chart (rotation, translation, log-scale): with ``f`` the whitened
world residual and ``J_f`` its Jacobians (:func:`points.point_residual`),
``J_A = (J_f,A - f e_scale^T) / s_a`` and ``J_B = J_f,B / s_a``. Similarity3 only. Noise model ``Unit(3N)``.
"""

from __future__ import annotations

import gtsam
import numpy as np

from ._lie import sim3_pair_factor
from .points import checked_point_pair, point_residual


def relative_point_residual(A, B, X_a: np.ndarray, X_b: np.ndarray, w: np.ndarray, want_jac: bool = True):
    """(R, t, s) of both Sim(3) variables -> (r [3N], J_A [3N, 7], J_B [3N, 7]); ``w`` [N] = 1 / sigma."""
    f, JA, JB = point_residual(A, B, X_a, X_b, w, "sim3", want_jac)
    s_a = A[2]
    r = f / s_a
    if not want_jac:
        return r, None, None
    JA = JA / s_a
    JA[:, 6] -= r  # d(f / s_a) / d(log s_a) = J_f,scale / s_a - f / s_a
    return r, JA, JB / s_a


def make_relative_point_factor(
    key_a: int,
    key_b: int,
    X_a: np.ndarray,  # [N, 3] in key_a's local frame
    X_b: np.ndarray,  # [N, 3] in key_b's local frame
    sigma: float | np.ndarray,  # scalar or [N], key_a's local units
) -> gtsam.CustomFactor:
    """Batched loop-point factor between two Similarity3 variables, residual in key_a's units (3N)."""
    X_a, X_b, w = checked_point_pair("relative point factor", key_a, key_b, X_a, X_b, sigma)

    return sim3_pair_factor(
        gtsam.noiseModel.Unit.Create(3 * len(X_a)), key_a, key_b,
        lambda A, B, jac: relative_point_residual(A, B, X_a, X_b, w, jac),
    )  # fmt: skip


__all__ = ["make_relative_point_factor", "relative_point_residual"]
