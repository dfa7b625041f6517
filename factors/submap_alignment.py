"""Submap alignment (SING3R): two submaps chained through their shared keyframe, rigid part only.

Submap i shares its frame 0 with frame K of submap i-1, so
``T_world(i, j) = T_world(i-1, K) T_local(i, 0)^-1 T_local(i, j)`` and the relative transform of the
submap variables ``E = S_{i-1}^-1 S_i`` must equal ``Z = T_local(i-1, K) T_local(i, 0)^-1`` up to the
relative scale (which :mod:`factors.scale` constrains separately, with its own sigma).

Residual (dimension 6; rotation in radians, translation in the units of submap i-1's frame)::

    r = [ Log(R_Z^T R_E) ;  R_Z^T (t_E - t_Z) ]

with ``E: x -> s_E R_E x + t_E``. Variables: Pose3 or Similarity3 (``group``); the Sim(3) log-scale
column of the Jacobian is zero except through ``t_E`` for the first variable.
"""

from __future__ import annotations

import gtsam
import numpy as np

from ._lie import (
    check_group,
    check_shape,
    fill,
    group_dim,
    pose_sigmas,
    read_transform,
    skew_batch,
    so3_log,
    so3_right_jacobian_inv,
)
from .errors import FactorInputError


def alignment_residual(A, B, Z: np.ndarray, group: str, want_jac: bool = True):
    """``A``, ``B``: (R, t, s) of the two variables; ``Z`` [4, 4] rigid -> (r [6], J_A [6, d], J_B [6, d])."""
    RA, tA, sA = A
    RB, tB, sB = B
    RZ, tZ = Z[:3, :3], Z[:3, 3]
    RE = RA.T @ RB
    tE = RA.T @ (tB - tA) / sA
    r_rot = so3_log(RZ.T @ RE)
    r = np.concatenate([r_rot, RZ.T @ (tE - tZ)])
    if not want_jac:
        return r, None, None
    d = group_dim(group)
    JA, JB = np.zeros((6, d)), np.zeros((6, d))
    Jr = so3_right_jacobian_inv(r_rot)
    JB[0:3, 0:3] = Jr
    JA[0:3, 0:3] = -Jr @ RE.T
    JB[3:6, 3:6] = RZ.T @ RE * (sB / sA)
    JA[3:6, 0:3] = RZ.T @ skew_batch(tE[None])[0]
    JA[3:6, 3:6] = -RZ.T
    if group == "sim3":
        JA[3:6, 6] = -RZ.T @ tE
    return r, JA, JB


def make_submap_alignment_factor(
    key_a: int,
    key_b: int,
    T_a_b: np.ndarray,  # [4, 4] rigid: measured pose of b's frame in a's frame
    rot_sigma: float,
    trans_sigma: float,
    group: str = "sim3",
) -> gtsam.CustomFactor:
    """Rigid 6-dof alignment of variable ``key_b`` to ``key_a``: ``key_a^-1 key_b ~ T_a_b`` (scale free).

    For SING3R pass ``T_a_b = T_local(i-1, K) @ inv(T_local(i, 0))``.
    """
    check_group(group)
    Z = check_shape("T_a_b", T_a_b, (4, 4))
    if not np.allclose(Z[:3, :3] @ Z[:3, :3].T, np.eye(3), atol=1e-5) or not np.allclose(Z[3], [0, 0, 0, 1]):
        raise FactorInputError("T_a_b must be a rigid 4x4 transform (orthonormal rotation, last row 0 0 0 1)")
    noise = gtsam.noiseModel.Diagonal.Sigmas(pose_sigmas(rot_sigma, trans_sigma))

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H) -> np.ndarray:
        ka, kb = this.keys()
        r, JA, JB = alignment_residual(
            read_transform(values, ka, group), read_transform(values, kb, group), Z, group, H is not None
        )
        fill(H, 0, JA)
        fill(H, 1, JB)
        return r

    return gtsam.CustomFactor(noise, [key_a, key_b], error)
