"""One evaluation of an estimated trajectory against ground truth: association, alignment, ATE, RPE.

:func:`evaluate` works on :class:`gsslam.types.Trajectory` values (pure: no files;
:func:`gsslam.run.evaluate.evaluate_files` reads them for ``gsslam eval``). The result is an
:class:`EvalReport` with ``to_dict()`` (JSON-able) and ``table_rows()`` (for the CLI table).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from gsslam.eval import EvalError
from gsslam.eval.association import Association
from gsslam.eval.ate import AteResult, compute_ate
from gsslam.eval.rpe import RpeResult, compute_rpe
from gsslam.types import Trajectory

_log = logging.getLogger(__name__)


@dataclass(frozen=True)
class EvalReport:
    """Everything ``gsslam eval`` reports; ``rpe`` is computed on the aligned estimate."""

    gt_name: str
    est_name: str
    align: str
    max_dt: float
    n_gt: int
    n_est: int
    association: Association
    ate: AteResult
    rpe: RpeResult

    def to_dict(self) -> dict:
        return {
            "ground_truth": self.gt_name,
            "estimate": self.est_name,
            "poses": {"ground_truth": self.n_gt, "estimate": self.n_est},
            "association": {"max_dt_s": self.max_dt, **self.association.to_dict()},
            "ate": self.ate.to_dict(),
            "rpe": self.rpe.to_dict(),
        }

    def table_rows(self) -> list[tuple[str, str]]:
        a, t, r = self.ate.stats, self.rpe.translation, self.rpe.rotation_deg
        rows = [
            (
                "pairs",
                f"{len(self.association)} (gt {self.n_gt}, est {self.n_est}, max |dt| "
                f"{self.association.dt.max():.4f} s <= {self.max_dt} s)",
            ),
            ("alignment", f"{self.ate.alignment.method}, scale {self.ate.alignment.scale:.6f}"),
        ]
        stats = ("rmse", "mean", "median", "std", "min", "max")
        rows += [(f"ATE {k}", f"{getattr(a, k):.6f} m") for k in stats]
        rows += [
            (f"RPE trans rmse (d={self.rpe.delta})", f"{t.rmse:.6f} m"),
            (f"RPE trans mean (d={self.rpe.delta})", f"{t.mean:.6f} m"),
            (f"RPE rot rmse (d={self.rpe.delta})", f"{r.rmse:.6f} deg"),
            (f"RPE rot mean (d={self.rpe.delta})", f"{r.mean:.6f} deg"),
        ]
        return rows


class TimeOrderError(EvalError):
    """A trajectory's timestamps are not strictly increasing."""


def check_time_order(traj: Trajectory, name: str) -> None:
    """Refuse a trajectory whose timestamps are unsorted or repeated: RPE pairs poses in order."""
    t = traj.timestamps
    bad = np.flatnonzero(np.diff(t) <= 0)
    if len(bad):
        i = int(bad[0]) + 1
        kind = "repeats" if t[i] == t[i - 1] else "comes before"
        raise TimeOrderError(
            f"{name}: pose {i + 1} (t={float(t[i])!r}) {kind} the pose above it (t={float(t[i - 1])!r}); "
            "timestamps must be strictly increasing: sort the file by time (e.g. sort -g -k1) "
            "and drop repeated stamps"
        )


def evaluate(
    gt: Trajectory,
    est: Trajectory,
    align: str = "sim3",
    max_dt: float = 0.02,
    rpe_delta: int = 1,
    gt_name: str = "ground truth",
    est_name: str = "estimate",
    one_to_one: bool = True,
) -> EvalReport:
    """Associate, align (``sim3`` | ``se3`` | ``none``), then ATE and RPE; the inputs are not modified.

    ``one_to_one=False`` reproduces evo's pairing exactly (see :mod:`gsslam.eval.association`).
    Both trajectories must be in strictly increasing time order (RPE pairs consecutive poses).
    """
    check_time_order(gt, gt_name)
    check_time_order(est, est_name)
    ate, assoc = compute_ate(gt, est, align=align, max_dt=max_dt, one_to_one=one_to_one)
    gt_poses = gt.poses[assoc.gt_indices]
    est_aligned = ate.alignment.apply_poses(est.poses[assoc.est_indices])
    rpe = compute_rpe(gt_poses, est_aligned, rpe_delta)
    _log.debug("ATE rmse %.6f m over %d pairs (%s)", ate.stats.rmse, len(assoc), align)
    return EvalReport(gt_name, est_name, align, float(max_dt), len(gt), len(est), assoc, ate, rpe)
