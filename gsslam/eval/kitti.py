"""KITTI odometry metrics: relative translation (%) and rotation (deg / 100 m) error over sub-sequences.

Same definition as the KITTI odometry devkit (``evaluate_odometry.cpp``, Geiger et al. 2012):

- ``dist[i]``: distance travelled along the ground truth up to pose ``i`` (sum of position steps);
- every ``step``-th pose (10 in the devkit) starts a sub-sequence of each length ``L`` in
  100, 200, ..., 800 m; it ends at the first pose ``j`` with ``dist[j] > dist[i] + L`` (skipped when
  the trajectory is too short);
- the error of a sub-sequence is ``E = (P_i^-1 P_j)^-1 (Q_i^-1 Q_j)`` (``P`` estimate, ``Q`` ground
  truth); ``t_err = |t(E)| / L`` and ``r_err = angle(R(E)) / L`` with the angle
  ``acos(clamp((trace(R) - 1) / 2, -1, 1))``;
- ``t_rel`` is the mean ``t_err`` over all sub-sequences in percent, ``r_rel`` the mean ``r_err`` in
  degrees per 100 m (the devkit stores radians per metre; papers print deg/100 m).

The poses must be paired (same index = same frame); indices stand for frames, so for an estimate
with gaps pass the associated pairs. Relative poses are unchanged by a rigid alignment, so an
SE(3)-aligned or unaligned estimate gives the same numbers; a monocular estimate needs its Sim(3)
scale applied first (the aligned poses of :class:`gsslam.eval.align.Alignment.apply_poses`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from gsslam.eval import EvalError

KITTI_LENGTHS_M = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)
KITTI_STEP = 10


class KittiMetricError(EvalError):
    """The poses for t_rel / r_rel are not paired or the lengths / step are invalid."""


@dataclass(frozen=True)
class KittiResult:
    """``t_rel_pct`` (%) and ``r_rel_deg_per_100m``; ``None`` when no sub-sequence fits the trajectory.

    ``per_length`` maps each length (m) that had sub-sequences to ``(t_rel %, r_rel deg/100 m, count)``.
    """

    t_rel_pct: float | None
    r_rel_deg_per_100m: float | None
    segments: int
    per_length: dict[float, tuple[float, float, int]] = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {
            "t_rel_pct": self.t_rel_pct,
            "r_rel_deg_per_100m": self.r_rel_deg_per_100m,
            "segments": self.segments,
            "per_length": {
                str(k): {"t_rel_pct": t, "r_rel_deg_per_100m": r, "segments": n}
                for k, (t, r, n) in self.per_length.items()
            },
        }


def path_distances(poses: np.ndarray) -> np.ndarray:  # [N, 4, 4] -> [N] metres travelled up to each pose
    steps = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(steps)])


def _inv(T: np.ndarray) -> np.ndarray:  # [N, 4, 4] -> [N, 4, 4]
    # A general inverse, as the devkit: KITTI's rotations are orthonormal only to ~1e-6, and a
    # transpose would move t_rel by ~1e-8 relative.
    return np.linalg.inv(T)


def kitti_relative_errors(
    gt_poses: np.ndarray,
    est_poses: np.ndarray,
    lengths: tuple[float, ...] = KITTI_LENGTHS_M,
    step: int = KITTI_STEP,
) -> KittiResult:
    """t_rel / r_rel of paired poses ``gt_poses`` [N, 4, 4] and ``est_poses`` [N, 4, 4] (T_world_cam)."""
    gt = np.asarray(gt_poses, dtype=np.float64)
    est = np.asarray(est_poses, dtype=np.float64)
    if gt.shape != est.shape or gt.ndim != 3 or gt.shape[1:] != (4, 4):
        raise KittiMetricError(f"t_rel needs paired [N, 4, 4] poses, got {gt.shape} and {est.shape}")
    if int(step) != step or step < 1 or not lengths or min(lengths) <= 0:
        raise KittiMetricError(f"t_rel needs step >= 1 and positive lengths, got step={step}, {lengths}")
    dist = path_distances(gt)
    first = np.arange(0, len(gt), int(step))
    t_all: list[np.ndarray] = []
    r_all: list[np.ndarray] = []
    per_length: dict[float, tuple[float, float, int]] = {}
    for L in lengths:
        # first pose j with dist[j] > dist[i] + L (the devkit's strict inequality); len(gt) = none
        last = np.searchsorted(dist, dist[first] + L, side="right")
        ok = last < len(gt)
        if not ok.any():
            continue
        i, j = first[ok], last[ok]
        d_gt = _inv(gt[i]) @ gt[j]
        d_est = _inv(est[i]) @ est[j]
        E = _inv(d_est) @ d_gt
        t_err = np.linalg.norm(E[:, :3, 3], axis=1) / L
        cos = np.clip((np.trace(E[:, :3, :3], axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
        r_err = np.arccos(cos) / L
        t_all.append(t_err)
        r_all.append(r_err)
        per_length[float(L)] = (100.0 * float(t_err.mean()), 100.0 * np.degrees(float(r_err.mean())), len(i))
    if not t_all:
        return KittiResult(None, None, 0, {})
    t, r = np.concatenate(t_all), np.concatenate(r_all)
    return KittiResult(100.0 * float(t.mean()), 100.0 * float(np.degrees(r.mean())), len(t), per_length)
