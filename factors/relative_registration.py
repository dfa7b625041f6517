"""Relative registration factor: keyframe poses measured against the map, relative to the map's owner submap.

The mapper registers keyframe k of a new submap n against the converged Gaussians; those were seeded
by the keyframes of older submaps, and move with them when the graph moves them (a loop). The
registration is therefore a measurement of the keyframe's rigid pose in the frame of the submap ``o``
that owns the Gaussians which explain the view (the *owner*, the largest share of the rendered weight):
``T_m = (R_m, t_m) = S_o^-1 T_world_cam`` at the moment of the registration (``o``'s local frame and
units), with a 6x6 information ``Lambda_k`` over the right perturbation ``(phi, rho)`` of that pose.
The graph predicts the camera in ``o``'s frame from the two Sim(3) variables and the keyframe's fixed
local pose ``T_local = (R_l, t_l)`` (submap n's units); with ``S = (R, t, s)`` (``x -> s R x + t``)::

    R_c = R_o^T R_n R_l          t_c = R_o^T (s_n R_n t_l + t_n - t_o) / s_o
    r_k = L_k [ Log(R_m^T R_c) ; R_m^T (t_c - t_m) ]         L_k^T L_k = Lambda_k

dimension 6 per keyframe (6N for the keyframes of one submap registered against one owner), whitened
(unit noise model). Unlike :mod:`factors.registration` (the same measurement as an absolute prior in the
chain frame) it moves with the owner: a loop that moves ``o`` moves the constraint on ``n`` with it.
Jacobians in GTSAM's chart ``S' = S Exp(omega, u[, lambda])``:

- new submap n: rotation rows ``Jr^-1(r_rot) R_l^T``; translation rows
  ``R_m^T (s_n / s_o) R_o^T R_n [-[t_l]x, I, t_l]`` (as :mod:`factors.registration`, divided by ``s_o``);
- owner o: rotation rows ``-Jr^-1(r_rot) R_c^T``; translation rows ``R_m^T [[t_c]x, -I, -t_c]``.
"""

from __future__ import annotations

import gtsam
import numpy as np

from ._lie import (
    check_group,
    fill,
    group_dim,
    read_transform,
    skew_batch,
    so3_log,
    so3_right_jacobian_inv,
)
from .errors import FactorInputError
from .registration import registration_inputs


def make_relative_registration_factor(
    key_owner: int,
    key_new: int,
    T_local_cam: np.ndarray,  # [N, 4, 4] rigid, submap n's units: keyframe poses inside the new submap
    T_owner_cam: np.ndarray,  # [N, 4, 4] rigid, owner units: the registered camera poses in the owner's frame
    information: np.ndarray,  # [N, 6, 6] over (phi, rho) of the measured pose, owner units
    group: str = "sim3",
) -> gtsam.CustomFactor:
    """Batched relative registration of N keyframes of submap ``key_new`` against owner ``key_owner``."""
    check_group(group)
    if int(key_owner) == int(key_new):
        raise FactorInputError("relative registration factor: the owner and the new submap must differ")
    L, Rl, tl, Rm, tm = registration_inputs(
        "relative registration factor", T_local_cam, ("T_owner_cam", T_owner_cam), information
    )
    n, d = len(Rl), group_dim(group)

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H) -> np.ndarray:
        ko, kn = this.keys()
        Ro, to, so = read_transform(values, ko, group)
        Rn, tn, sn = read_transform(values, kn, group)
        r = np.empty((n, 6))
        Jo = np.zeros((n, 6, d))
        Jn = np.zeros((n, 6, d))
        for k in range(n):
            Rc = Ro.T @ Rn @ Rl[k]
            tc = Ro.T @ (sn * Rn @ tl[k] + tn - to) / so
            r_rot = so3_log(Rm[k].T @ Rc)
            r[k, :3] = r_rot
            r[k, 3:] = Rm[k].T @ (tc - tm[k])
            if H is not None:
                Jinv = so3_right_jacobian_inv(r_rot)
                Jn[k, :3, 0:3] = Jinv @ Rl[k].T
                A = Rm[k].T @ ((sn / so) * Ro.T @ Rn)
                Jn[k, 3:, 0:3] = -A @ skew_batch(tl[k][None])[0]
                Jn[k, 3:, 3:6] = A
                Jo[k, :3, 0:3] = -Jinv @ Rc.T
                Jo[k, 3:, 0:3] = Rm[k].T @ skew_batch(tc[None])[0]
                Jo[k, 3:, 3:6] = -Rm[k].T
                if group == "sim3":
                    Jn[k, 3:, 6] = A @ tl[k]
                    Jo[k, 3:, 6] = -Rm[k].T @ tc
        if H is not None:
            fill(H, 0, np.einsum("nij,njk->nik", L, Jo).reshape(6 * n, d))
            fill(H, 1, np.einsum("nij,njk->nik", L, Jn).reshape(6 * n, d))
        return np.einsum("nij,nj->ni", L, r).reshape(6 * n)

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(6 * n), [key_owner, key_new], error)


__all__ = ["make_relative_registration_factor"]
