"""Keyframe pose: a measured ``T_world_cam`` of one keyframe, expressed on its submap's variable.

The graph's variables are submap transforms ``S``; a keyframe's pose is ``rigid(S T_local_cam)`` with
its fixed local pose ``L = T_local_cam`` (rigid, in submap units). This factor maps a measurement of the
keyframe's pose (GPS + compass, motion capture, a user's anchor) onto ``S`` (an "expression factor":
no keyframe variable is added to the graph).

Residual (dimension 6; rotation in radians, translation in world units)::

    T = rigid(S L):  R_T = R_S R_L,  t_T = s R_S t_L + t_S
    r = [ Log(R_M^T R_T) ;  R_M^T (t_T - t_M) ]

with the measurement ``M = (R_M, t_M)``. The scale of ``S`` enters through ``t_T`` only. Variable: Pose3
or Similarity3 (``group``).
"""

from __future__ import annotations

import gtsam
import numpy as np

from ._lie import (
    action_jacobian,
    check_group,
    check_shape,
    fill,
    pose_sigmas,
    read_transform,
    so3_log,
    so3_right_jacobian_inv,
)
from .errors import FactorInputError


def check_rigid(name: str, T) -> np.ndarray:
    T = check_shape(name, T, (4, 4))
    if not np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-5) or not np.allclose(T[3], [0, 0, 0, 1]):
        raise FactorInputError(
            f"{name} must be a rigid 4x4 transform (orthonormal rotation, last row 0 0 0 1)"
        )
    return T


def keyframe_pose_residual(S, L: np.ndarray, M: np.ndarray, group: str, want_jac: bool = True):
    """``S``: (R, t, s) of the submap; ``L``, ``M`` [4, 4] rigid -> (r [6], J [6, dim])."""
    RS, tS, s = S
    RT = RS @ L[:3, :3]
    tT = s * RS @ L[:3, 3] + tS
    RM, tM = M[:3, :3], M[:3, 3]
    r_rot = so3_log(RM.T @ RT)
    r = np.concatenate([r_rot, RM.T @ (tT - tM)])
    if not want_jac:
        return r, None
    J = np.zeros((6, 7 if group == "sim3" else 6))
    # rotation: R_S Exp(w) R_L = R_T Exp(R_L^T w)
    J[0:3, 0:3] = so3_right_jacobian_inv(r_rot) @ L[:3, :3].T
    J[3:6] = RM.T @ action_jacobian(RS, s, L[None, :3, 3], group)[0]  # t_T is S acting on t_L
    return r, J


def make_keyframe_pose_factor(
    key: int,
    T_local_cam: np.ndarray,  # [4, 4] rigid: the keyframe in its submap's local frame (submap units)
    T_world_cam: np.ndarray,  # [4, 4] rigid: the measured keyframe pose (world units)
    rot_sigma: float,
    trans_sigma: float,
    group: str = "sim3",
) -> gtsam.CustomFactor:
    """A prior on the pose of a keyframe whose submap variable is ``key``: ``rigid(S L) ~ T_world_cam``."""
    check_group(group)
    L = check_rigid("T_local_cam", T_local_cam)
    M = check_rigid("T_world_cam", T_world_cam)
    noise = gtsam.noiseModel.Diagonal.Sigmas(pose_sigmas(rot_sigma, trans_sigma))

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H) -> np.ndarray:
        r, J = keyframe_pose_residual(
            read_transform(values, this.keys()[0], group), L, M, group, H is not None
        )
        fill(H, 0, J)
        return r

    return gtsam.CustomFactor(noise, [key], error)
