"""Registration factor: keyframe poses measured against the Gaussian map, on their submap's variable.

The mapper registers keyframe k of submap i against the map (SING3R's intra-submap refinement:
photometric L1 under the alpha mask + scale-invariant depth) and returns the rigid camera pose it
found, ``T_m = (R_m, t_m)`` (chain frame, chain units), with a 6x6 information matrix ``Lambda_k``
over the right perturbation ``(phi, rho)`` of that pose (Gauss-Newton Hessian of the registration's
residuals at its optimum). The graph predicts the camera from the submap variable ``S = (R_s, t_s, s)``
and the keyframe's fixed local pose ``T_local = (R_l, t_l)`` (submap units)::

    R_c = R_s R_l                 t_c = s R_s t_l + t_s
    r_k = L_k [ Log(R_m^T R_c) ; R_m^T (t_c - t_m) ]         L_k^T L_k = Lambda_k

dimension 6 per keyframe (6N for the batch of one submap), whitened (unit noise model). Jacobians in
GTSAM's chart ``S' = S Exp(omega, u[, lambda])``: rotation rows ``Jr^-1(r_rot) R_l^T`` for omega;
translation rows ``R_m^T s R_s [-[t_l]x, I, t_l]``. The first block is a relative-pose prior of the
camera, so the factor pulls the submap (rotation, translation and, through ``t_l``, its scale) toward
the pose at which the map explains the keyframe best, as firmly as the registration was sure of it.
"""

from __future__ import annotations

import gtsam
import numpy as np

from ._lie import (
    check_group,
    check_shape,
    fill,
    group_dim,
    read_transform,
    skew_batch,
    so3_log,
    so3_right_jacobian_inv,
)
from .errors import FactorInputError


def sqrt_information_batch(info: np.ndarray) -> np.ndarray:  # [N, 6, 6] -> [N, 6, 6]: upper L, L^T L = info
    out = np.empty_like(info)
    for k, A in enumerate(info):
        A = 0.5 * (A + A.T)
        try:
            out[k] = np.linalg.cholesky(A).T
        except np.linalg.LinAlgError as e:
            raise FactorInputError(f"information matrix {k} is not positive definite") from e
    return out


def registration_inputs(
    what: str,  # the factor's name, for errors
    T_local_cam: np.ndarray,  # [N, 4, 4] keyframe poses inside the submap
    measured: tuple[str, np.ndarray],  # (name, [N, 4, 4] registered camera poses)
    information: np.ndarray,  # [N, 6, 6]
):  # -> (sqrt information [N, 6, 6], R_local [N, 3, 3], t_local [N, 3], R_measured, t_measured)
    """The checked inputs of a batched registration factor (absolute or relative)."""
    Tl = check_shape("T_local_cam", T_local_cam, (None, 4, 4))
    Tm = check_shape(measured[0], measured[1], (len(Tl), 4, 4))
    info = check_shape("information", information, (len(Tl), 6, 6))
    if len(Tl) == 0:
        raise FactorInputError(f"{what}: need at least one keyframe")
    return sqrt_information_batch(info), Tl[:, :3, :3], Tl[:, :3, 3], Tm[:, :3, :3], Tm[:, :3, 3]


def make_registration_factor(
    key: int,
    T_local_cam: np.ndarray,  # [N, 4, 4] rigid, submap units: keyframe poses inside the submap
    T_chain_cam: np.ndarray,  # [N, 4, 4] rigid, chain units: the registered (measured) camera poses
    information: np.ndarray,  # [N, 6, 6] over (phi, rho) of the measured pose, chain units
    group: str = "sim3",
) -> gtsam.CustomFactor:
    """Batched registration factor of N keyframes of one submap on its variable, dimension 6N."""
    check_group(group)
    L, Rl, tl, Rm, tm = registration_inputs(
        "registration factor", T_local_cam, ("T_chain_cam", T_chain_cam), information
    )
    n, d = len(Rl), group_dim(group)

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H) -> np.ndarray:
        R, t, s = read_transform(values, this.keys()[0], group)
        r = np.empty((n, 6))
        J = np.zeros((n, 6, d))
        for k in range(n):
            r_rot = so3_log(Rm[k].T @ R @ Rl[k])
            r[k, :3] = r_rot
            r[k, 3:] = Rm[k].T @ (s * R @ tl[k] + t - tm[k])
            if H is not None:
                J[k, :3, 0:3] = so3_right_jacobian_inv(r_rot) @ Rl[k].T
                A = Rm[k].T @ (s * R)
                J[k, 3:, 0:3] = -A @ skew_batch(tl[k][None])[0]
                J[k, 3:, 3:6] = A
                if group == "sim3":
                    J[k, 3:, 6] = A @ tl[k]
        if H is not None:
            fill(H, 0, np.einsum("nij,njk->nik", L, J).reshape(6 * n, d))
        return np.einsum("nij,nj->ni", L, r).reshape(6 * n)

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(6 * n), [key], error)
