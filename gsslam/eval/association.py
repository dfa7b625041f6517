"""Pair the poses of two trajectories by timestamp (nearest neighbour within ``max_dt``).

Same rule as evo's ``sync.associate_trajectories`` (nearest-time method): every timestamp of the
trajectory with fewer poses is matched to the nearest timestamp of the other one if they differ by
at most ``max_dt``; on a tie the earlier one wins. Unlike evo, the pairing is strictly one-to-one:
when two stamps pick the same partner, only the closer keeps it (evo would pair it twice; this only
happens when ``max_dt`` exceeds half the sampling period of the longer trajectory).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gsslam.eval import EvalError
from gsslam.types import Trajectory


class AssociationError(EvalError):
    """No (or too few) pose pairs could be associated by timestamp."""


@dataclass(frozen=True)
class Association:
    """Indices of the paired poses in ``gt`` and ``est`` ([M] each, in increasing gt time order) and
    the absolute time differences ``dt`` [M] in seconds."""

    gt_indices: np.ndarray
    est_indices: np.ndarray
    dt: np.ndarray

    def __len__(self) -> int:
        return len(self.gt_indices)

    def to_dict(self) -> dict:
        return {
            "pairs": len(self),
            "max_abs_dt_s": float(self.dt.max()) if len(self) else None,
            "mean_abs_dt_s": float(self.dt.mean()) if len(self) else None,
        }


def _nearest(short: np.ndarray, long: np.ndarray, max_dt: float) -> tuple[np.ndarray, np.ndarray]:
    """For each stamp of ``short`` [S] the index into ``long`` [L] of its nearest stamp (or -1)."""
    order = np.argsort(long, kind="stable")
    s_long = long[order]
    ub = np.clip(np.searchsorted(s_long, short, side="right"), 0, len(s_long) - 1)
    lb = ub - 1
    diff_ub = s_long[ub] - short  # may be negative when short lies beyond the last stamp
    diff_lb = np.where(lb >= 0, short - s_long[np.maximum(lb, 0)], np.inf)
    pick_ub = (np.abs(diff_ub) <= max_dt) & (np.abs(diff_ub) < diff_lb)
    pick_lb = ~pick_ub & (diff_lb <= max_dt) & (diff_lb <= np.abs(diff_ub))
    idx = np.full(len(short), -1, dtype=np.int64)
    idx[pick_ub] = order[ub[pick_ub]]
    idx[pick_lb] = order[lb[pick_lb]]
    return idx, np.where(pick_ub, np.abs(diff_ub), diff_lb)


def associate(gt: Trajectory, est: Trajectory, max_dt: float = 0.02) -> Association:
    """Pair ``gt`` and ``est`` poses whose timestamps differ by at most ``max_dt`` seconds."""
    if not max_dt >= 0:
        raise AssociationError(f"max_dt must be >= 0 seconds, got {max_dt}")
    if len(gt) == 0 or len(est) == 0:
        raise AssociationError(f"cannot associate an empty trajectory ({len(gt)} gt, {len(est)} est poses)")
    est_shorter = len(est) < len(gt)
    short, long = (est, gt) if est_shorter else (gt, est)
    idx_long, dt = _nearest(short.timestamps, long.timestamps, max_dt)
    idx_short = np.flatnonzero(idx_long >= 0)
    idx_long, dt = idx_long[idx_short], dt[idx_short]
    # One-to-one: a partner claimed twice stays with the closer stamp (the earlier one on a tie).
    keep = np.ones(len(idx_short), dtype=bool)
    order = np.lexsort((idx_short, dt, idx_long))  # by partner, then |dt|, then own index
    seen = set()
    for k in order:
        if idx_long[k] in seen:
            keep[k] = False
        seen.add(int(idx_long[k]))
    idx_short, idx_long, dt = idx_short[keep], idx_long[keep], dt[keep]
    gt_idx, est_idx = (idx_long, idx_short) if est_shorter else (idx_short, idx_long)
    if len(gt_idx) == 0:
        raise AssociationError(
            f"no timestamps of the estimate ({est.timestamps.min():.6f}..{est.timestamps.max():.6f} s) are "
            f"within max_dt={max_dt} s of the ground truth ({gt.timestamps.min():.6f}.."
            f"{gt.timestamps.max():.6f} s); check that both files use the same clock and format"
        )
    o = np.argsort(gt.timestamps[gt_idx], kind="stable")
    return Association(gt_idx[o], est_idx[o], dt[o])
