"""Keyframe tie: a keyframe's body pose *variable* ``X`` (Pose3) tied to its pose through its submap ``S``.

IMU factors need a Pose3 variable per keyframe; the visual graph expresses a keyframe's camera pose as
``rigid(S L)`` with the fixed local pose ``L = T_local_cam`` (see :mod:`keyframe_pose`). This factor
compares the two, with the rigid camera-body extrinsic ``E = T_cam_body`` (metric)::

    T = rigid(S L)  (model),   M = X E^-1  (the camera pose implied by the body variable)
    r = [ Log(R_M^T R_T) ;  R_M^T (t_T - t_M) / s ]      (dimension 6; rad, SUBMAP units)

i.e. the residual of :func:`keyframe_pose.keyframe_pose_residual` with the measurement made a variable,
its translation divided by the submap's scale ``s`` (1 for Pose3). The tie stands for the error of the
*visual* local pose ``L``, which is in the submap's units; measured in world units, a tie would cost
``s^2`` times less when the submap shrinks, and with metric IMU positions on the other side the
optimum shrinks every submap (teddy-200 mono + IMU: 5.5 % too small, 1.1 % in submap units; see
docs/results.md "IMU in the run, session 5"). ``trans_sigma`` is therefore in submap units
(:func:`gsslam.graph.imu.add_keyframe_tie` converts a metric sigma with the submap's scale when the tie
is made). Keys: ``S`` (Similarity3 or Pose3, ``group``) and ``X`` (Pose3). Jacobian in ``X`` (right
chart, ``X Exp([phi; rho])``), with ``e = R_M^T (t_T - t_M)`` (the unscaled translation residual)::

    d r_rot = -Jl^-1(r_rot) R_bc^T dphi
    d r_t   = (([e]x R_bc^T + R_bc^T [t_bc]x) dphi - R_bc^T drho) / s

with ``T_body_cam = E^-1 = (R_bc, t_bc)``; in ``S`` the world-unit Jacobian divided by ``s``, and the
scale column (``s Exp(lambda)``) gains ``-e / s``.
"""

from __future__ import annotations

import gtsam
import numpy as np

from ._lie import check_group, fill, pose_sigmas, read_transform, skew_batch, so3_right_jacobian_inv
from .keyframe_pose import check_rigid, keyframe_pose_residual


def keyframe_tie_residual(S, X: np.ndarray, L: np.ndarray, T_body_cam: np.ndarray, group: str, want_jac=True):
    """``S``: (R, t, s); ``X``: [4, 4] body pose; ``L``, ``T_body_cam`` [4, 4] -> (r [6], J_S, J_X [6, 6]).

    The translation rows are in submap units (divided by ``s``); see the module docstring."""
    M = X @ T_body_cam
    r, J_S = keyframe_pose_residual(S, L, M, group, want_jac)
    s = float(S[2])
    e = r[3:].copy()  # world units
    r[3:] = e / s
    if not want_jac:
        return r, None, None
    J_S[3:6] /= s
    if group == "sim3":
        J_S[3:6, 6] -= e / s  # d(1 / s) / d lambda = -1 / s
    R_bc, t_bc = T_body_cam[:3, :3], T_body_cam[:3, 3]
    J_X = np.zeros((6, 6))
    J_X[0:3, 0:3] = -so3_right_jacobian_inv(-r[:3]) @ R_bc.T  # Jl^-1(w) = Jr^-1(-w)
    J_X[3:6, 0:3] = (skew_batch(e[None])[0] @ R_bc.T + R_bc.T @ skew_batch(t_bc[None])[0]) / s
    J_X[3:6, 3:6] = -R_bc.T / s
    return r, J_S, J_X


def make_keyframe_tie_factor(
    key_submap: int,
    key_body: int,
    T_local_cam: np.ndarray,  # [4, 4] rigid: the keyframe in its submap's local frame (submap units)
    T_cam_body: np.ndarray,  # [4, 4] rigid: the body (IMU) frame in the camera frame (metres)
    rot_sigma: float,  # rad
    trans_sigma: float,  # submap units (the residual's translation is divided by the submap's scale)
    group: str = "sim3",
) -> gtsam.CustomFactor:
    """Tie body pose ``X = x{f}`` to ``rigid(S L) T_cam_body``; see the module docstring."""
    check_group(group)
    L = check_rigid("T_local_cam", T_local_cam)
    T_body_cam = np.linalg.inv(check_rigid("T_cam_body", T_cam_body))
    noise = gtsam.noiseModel.Diagonal.Sigmas(pose_sigmas(rot_sigma, trans_sigma))

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H) -> np.ndarray:
        keys = this.keys()
        S = read_transform(values, keys[0], group)
        X = values.atPose3(keys[1]).matrix()
        r, J_S, J_X = keyframe_tie_residual(S, X, L, T_body_cam, group, H is not None)
        fill(H, 0, J_S)
        fill(H, 1, J_X)
        return r

    return gtsam.CustomFactor(noise, [key_submap, key_body], error)
