"""Relative pose of two submaps measured with a full 6x6 information, under a robust kernel (RGB-D ICP loops).

Dense point-to-plane ICP between a keyframe of submap ``a`` and one of submap ``b`` measures the rigid
relative transform of the two submap frames, ``Z = T_a_b`` (maps b-local points to a-local), and the
Gauss-Newton Hessian of its residuals ``Lambda`` [6, 6] over the right perturbation ``(omega, u)`` of
``Z`` (``Z' = Z Exp(omega, u)``; rotation first, GTSAM's order). With ``E = S_a^-1 S_b`` and
``E: x -> s_E R_E x + t_E``, the residual (dimension 6, whitened) is::

    r = L [ Log(R_Z^T R_E) ;  R_Z^T (t_E - t_Z) ]          L^T L = Lambda

i.e. :mod:`submap_alignment`'s residual (rotation in radians, translation in the units of a's frame,
scale free: RGB-D submaps are metric) whitened by the measurement's own information instead of two
diagonal sigmas: a direction the depth maps pin down (across a wall) is stiff, one they do not (along
it) is soft. A Huber kernel (threshold ``huber`` on the whitened norm) keeps a wrong loop from
dominating. Jacobians: ``L`` times :func:`submap_alignment.alignment_residual`'s (right-perturbation
chart, tested there and in tests/factors/). Pose3 or Similarity3 variables.
"""

from __future__ import annotations

import gtsam
import numpy as np

from ._lie import check_group, check_positive, check_shape, fill, read_transform
from .errors import FactorInputError
from .submap_alignment import alignment_residual


def sqrt_information(info: np.ndarray) -> np.ndarray:  # [6, 6] -> [6, 6] upper L with L^T L = info
    A = 0.5 * (info + info.T)
    try:
        return np.linalg.cholesky(A).T
    except np.linalg.LinAlgError as e:
        raise FactorInputError("relative pose information is not positive definite") from e


def make_relative_pose_factor(
    key_a: int,
    key_b: int,
    T_a_b: np.ndarray,  # [4, 4] rigid: measured pose of b's frame in a's frame
    information: np.ndarray,  # [6, 6] over (omega, u), the right perturbation of T_a_b
    huber: float = 0.0,  # Huber threshold on the whitened residual (0: none, plain Gaussian)
    group: str = "sim3",
) -> gtsam.CustomFactor:
    """``key_a^-1 key_b ~ T_a_b`` with information ``information`` (dimension 6, module docstring)."""
    check_group(group)
    Z = check_shape("T_a_b", T_a_b, (4, 4))
    if not np.allclose(Z[:3, :3] @ Z[:3, :3].T, np.eye(3), atol=1e-5) or not np.allclose(Z[3], [0, 0, 0, 1]):
        raise FactorInputError("T_a_b must be a rigid 4x4 transform (orthonormal rotation, last row 0 0 0 1)")
    if int(key_a) == int(key_b):
        raise FactorInputError("relative pose factor: the two keys must differ")
    L = sqrt_information(check_shape("information", information, (6, 6)))
    noise = gtsam.noiseModel.Unit.Create(6)
    if float(huber) > 0:
        noise = gtsam.noiseModel.Robust.Create(
            gtsam.noiseModel.mEstimator.Huber.Create(check_positive("huber", huber)), noise
        )

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H) -> np.ndarray:
        ka, kb = this.keys()
        r, JA, JB = alignment_residual(
            read_transform(values, ka, group), read_transform(values, kb, group), Z, group, H is not None
        )
        if H is not None:
            fill(H, 0, L @ JA)
            fill(H, 1, L @ JB)
        return L @ r

    return gtsam.CustomFactor(noise, [key_a, key_b], error)


__all__ = ["make_relative_pose_factor", "sqrt_information"]
