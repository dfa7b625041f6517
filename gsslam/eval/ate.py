"""Absolute trajectory error: position error of paired poses after alignment (evo's APE, translation part).

``e_i = | p_gt_i - (s R p_est_i + t) |`` in metres, summarised by :class:`ErrorStats`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gsslam.eval.align import Alignment, align_positions
from gsslam.eval.association import Association, associate
from gsslam.eval.stats import ErrorStats
from gsslam.types import Trajectory


@dataclass(frozen=True)
class AteResult:
    """ATE statistics (metres), the alignment used, and the per-pair errors ``errors`` [M]."""

    stats: ErrorStats
    alignment: Alignment
    errors: np.ndarray

    def to_dict(self) -> dict:
        return {"translation_m": self.stats.to_dict(), "alignment": self.alignment.to_dict()}


def ate_from_pairs(gt_xyz: np.ndarray, est_xyz: np.ndarray, align: str = "sim3") -> AteResult:
    """ATE of paired positions ``gt_xyz`` [M, 3], ``est_xyz`` [M, 3] after alignment ``align``."""
    alignment = align_positions(gt_xyz, est_xyz, align)
    errors = np.linalg.norm(np.asarray(gt_xyz) - alignment.apply_positions(est_xyz), axis=1)
    return AteResult(ErrorStats.from_errors(errors), alignment, errors)


def compute_ate(
    gt: Trajectory, est: Trajectory, align: str = "sim3", max_dt: float = 0.02, one_to_one: bool = True
) -> tuple[AteResult, Association]:
    """Associate ``est`` with ``gt`` by timestamp, align, and return the ATE with the association."""
    assoc = associate(gt, est, max_dt, one_to_one)
    result = ate_from_pairs(gt.positions[assoc.gt_indices], est.positions[assoc.est_indices], align)
    return result, assoc
