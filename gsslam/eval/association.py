"""Pair the poses of two trajectories by timestamp (nearest neighbour within ``max_dt``).

Same rule as evo's ``sync.associate_trajectories`` (nearest-time method): every timestamp of the
trajectory with fewer poses (the estimate, on equal length) is matched to the nearest timestamp of
the other one if they differ by at most ``max_dt``; on a tie the earlier one wins.

evo may pair one pose of the longer trajectory with two poses of the shorter one (when both are
nearest to it, e.g. across a gap in the ground truth). By default the pairing here is strictly
one-to-one: such a pose stays with the closer stamp only (the earlier on a tie).
``one_to_one=False`` keeps evo's pairs exactly.
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
    """Indices of the paired poses in ``gt`` and ``est`` ([M] each) and their absolute time
    differences ``dt`` [M] in seconds. Pairs follow the order of the shorter trajectory's poses, as in
    evo (time order when the files are sorted by time)."""

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


def associate(gt: Trajectory, est: Trajectory, max_dt: float = 0.02, one_to_one: bool = True) -> Association:
    """Pair ``gt`` and ``est`` poses whose timestamps differ by at most ``max_dt`` seconds."""
    if not max_dt >= 0:
        raise AssociationError(f"max_dt must be >= 0 seconds, got {max_dt}")
    if len(gt) == 0 or len(est) == 0:
        raise AssociationError(f"cannot associate an empty trajectory ({len(gt)} gt, {len(est)} est poses)")
    est_shorter = len(est) <= len(gt)  # as evo: on equal length, start from the estimate
    short, long = (est, gt) if est_shorter else (gt, est)
    idx_long, dt = _nearest(short.timestamps, long.timestamps, max_dt)
    idx_short = np.flatnonzero(idx_long >= 0)
    idx_long, dt = idx_long[idx_short], dt[idx_short]
    # One-to-one: a partner claimed twice stays with the closer stamp (the earlier one on a tie).
    if one_to_one:
        order = np.lexsort((idx_short, dt, idx_long))  # by partner, then |dt|, then own index
        first = np.ones(len(order), dtype=bool)
        first[1:] = idx_long[order][1:] != idx_long[order][:-1]
        keep = np.sort(order[first])
        idx_short, idx_long, dt = idx_short[keep], idx_long[keep], dt[keep]
    gt_idx, est_idx = (idx_long, idx_short) if est_shorter else (idx_short, idx_long)
    if len(gt_idx) == 0:
        raise AssociationError(
            f"no timestamps of the estimate ({est.timestamps.min():.6f}..{est.timestamps.max():.6f} s) are "
            f"within max_dt={max_dt} s of the ground truth ({gt.timestamps.min():.6f}.."
            f"{gt.timestamps.max():.6f} s); check that both files use the same clock and format"
        )
    return Association(gt_idx, est_idx, dt)
