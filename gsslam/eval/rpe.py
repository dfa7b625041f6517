"""Relative pose error over a fixed frame delta (evo's RPE with ``delta_unit=frames``, consecutive pairs).

For paired poses ``Q`` (ground truth) and ``P`` (estimate) and index pairs ``(i, i+d)`` with ``i`` in
``0, d, 2d, ...``: ``E_i = (Q_i^-1 Q_{i+d})^-1 (P_i^-1 P_{i+d})``. The translation error is ``|t(E_i)|``
(metres) and the rotation error the angle of ``R(E_i)`` (degrees). Poses are rigid; pass the aligned
estimate so that a Sim(3) alignment's scale applies to the relative translations.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gsslam.eval import EvalError
from gsslam.eval.stats import ErrorStats


class RpeError(EvalError):
    """The frame delta is invalid or the trajectories are too short for it."""


@dataclass(frozen=True)
class RpeResult:
    """RPE statistics for frame delta ``delta``: translation (m) and rotation (deg) per pair."""

    delta: int
    translation: ErrorStats
    rotation_deg: ErrorStats
    translation_errors: np.ndarray
    rotation_errors_deg: np.ndarray

    def to_dict(self) -> dict:
        return {
            "delta_frames": self.delta,
            "translation_m": self.translation.to_dict(),
            "rotation_deg": self.rotation_deg.to_dict(),
        }


def _rigid_inverse(T: np.ndarray) -> np.ndarray:  # [N, 4, 4] -> [N, 4, 4]
    Ti = np.zeros_like(T)
    Rt = np.swapaxes(T[:, :3, :3], 1, 2)
    Ti[:, :3, :3] = Rt
    Ti[:, :3, 3] = -np.einsum("nij,nj->ni", Rt, T[:, :3, 3])
    Ti[:, 3, 3] = 1.0
    return Ti


def rotation_angle_deg(R: np.ndarray) -> np.ndarray:  # [N, 3, 3] -> [N] degrees, accurate near 0 and pi
    v = np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], axis=1)
    cos = (np.trace(R, axis1=1, axis2=2) - 1.0) / 2.0
    return np.degrees(np.arctan2(np.linalg.norm(v, axis=1) / 2.0, cos))


def compute_rpe(gt_poses: np.ndarray, est_poses: np.ndarray, delta: int = 1) -> RpeResult:
    """RPE of paired poses ``gt_poses`` [M, 4, 4] and ``est_poses`` [M, 4, 4] (rigid, T_world_cam)."""
    gt_poses = np.asarray(gt_poses, dtype=np.float64)
    est_poses = np.asarray(est_poses, dtype=np.float64)
    if gt_poses.shape != est_poses.shape:
        raise RpeError(f"RPE needs paired poses of equal shape, got {gt_poses.shape} and {est_poses.shape}")
    if int(delta) != delta or delta < 1:
        raise RpeError(f"RPE frame delta must be a positive integer, got {delta}")
    delta = int(delta)
    ids = np.arange(0, len(gt_poses), delta)
    if len(ids) < 2:
        raise RpeError(
            f"RPE with delta={delta} frames needs at least {delta + 1} associated poses, got "
            f"{len(gt_poses)}; use a smaller --rpe-delta"
        )
    i, j = ids[:-1], ids[1:]
    Q_rel = _rigid_inverse(gt_poses[i]) @ gt_poses[j]
    P_rel = _rigid_inverse(est_poses[i]) @ est_poses[j]
    E = _rigid_inverse(Q_rel) @ P_rel
    t_err = np.linalg.norm(E[:, :3, 3], axis=1)
    r_err = rotation_angle_deg(E[:, :3, :3])
    return RpeResult(delta, ErrorStats.from_errors(t_err), ErrorStats.from_errors(r_err), t_err, r_err)
