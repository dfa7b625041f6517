"""Umeyama alignment of an estimated trajectory to ground truth: SE(3), Sim(3) or none.

The alignment ``T_gt_est`` (scale ``s``, rotation ``R``, translation ``t``) minimises
``sum_i |p_gt_i - (s R p_est_i + t)|^2`` over the associated positions (Umeyama 1991, via
:func:`gsslam.geometry.umeyama`). Applying it to a pose follows evo: the rotation block stays a
rotation, ``T -> [[R R_i, s R t_i + t], [0, 1]]`` (the camera is moved, not rescaled).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gsslam.eval import EvalError
from gsslam.geometry import make_T, umeyama

ALIGN_METHODS = ("sim3", "se3", "none")


class AlignmentError(EvalError):
    """The alignment method is unknown or the positions do not determine an alignment."""


@dataclass(frozen=True)
class Alignment:
    """``T_gt_est`` as rotation [3, 3], translation [3] and scale; ``method`` is sim3 | se3 | none."""

    method: str
    rotation: np.ndarray
    translation: np.ndarray
    scale: float

    @property
    def matrix(self) -> np.ndarray:  # [4, 4] Sim(3) ``T_gt_est``
        return make_T(self.rotation, self.translation, self.scale)

    def apply_positions(self, positions: np.ndarray) -> np.ndarray:  # [N, 3] -> [N, 3]
        return self.scale * np.asarray(positions) @ self.rotation.T + self.translation

    def apply_poses(self, poses: np.ndarray) -> np.ndarray:  # [N, 4, 4] -> new [N, 4, 4]
        out = np.array(poses, dtype=np.float64, copy=True)
        out[:, :3, :3] = self.rotation @ out[:, :3, :3]
        out[:, :3, 3] = self.apply_positions(out[:, :3, 3])
        return out

    def to_dict(self) -> dict:
        return {
            "method": self.method,
            "scale": float(self.scale),
            "rotation": self.rotation.tolist(),
            "translation": self.translation.tolist(),
        }


def identity_alignment() -> Alignment:
    return Alignment("none", np.eye(3), np.zeros(3), 1.0)


def align_positions(gt_xyz: np.ndarray, est_xyz: np.ndarray, method: str = "sim3") -> Alignment:
    """Fit the alignment mapping ``est_xyz`` [N, 3] onto ``gt_xyz`` [N, 3] (paired rows)."""
    if method not in ALIGN_METHODS:
        raise AlignmentError(f"unknown alignment {method!r}; choose one of: {', '.join(ALIGN_METHODS)}")
    if method == "none":
        return identity_alignment()
    gt_xyz = np.asarray(gt_xyz, dtype=np.float64)
    est_xyz = np.asarray(est_xyz, dtype=np.float64)
    if len(est_xyz) < 3:
        raise AlignmentError(
            f"{method} alignment needs at least 3 associated poses, got {len(est_xyz)}; check the "
            "timestamps (--max-dt) or use --align none"
        )
    # Like evo, the cross-covariance needs rank >= 2 (the points are not all on one line); evo tests
    # the singular values against machine epsilon, here relative to the largest one (scale-free).
    xs, xd = est_xyz - est_xyz.mean(0), gt_xyz - gt_xyz.mean(0)
    sv = np.linalg.svd(xd.T @ xs / len(xs), compute_uv=False)
    if not sv[1] > 1e-10 * sv[0]:
        raise AlignmentError(
            f"{method} alignment is undetermined: the {len(est_xyz)} associated positions are (nearly) "
            "collinear or identical; use --align none"
        )
    T = umeyama(est_xyz, gt_xyz, with_scale=(method == "sim3"))
    if method == "se3":  # the rotation block is a rotation: no scale, not even 1 - 1e-15
        return Alignment(method, T[:3, :3].copy(), T[:3, 3].copy(), 1.0)
    s = float(np.cbrt(np.linalg.det(T[:3, :3])))
    return Alignment(method, T[:3, :3] / s, T[:3, 3].copy(), s)
