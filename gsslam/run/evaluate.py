"""``gsslam eval``: read two trajectory files, evaluate them (:mod:`gsslam.eval`), optionally plot."""

from __future__ import annotations

from pathlib import Path

from gsslam.eval.report import EvalReport, evaluate
from gsslam.io.trajectory import read_trajectory


def evaluate_files(
    gt: str | Path,
    est: str | Path,
    align: str = "sim3",
    fmt: str = "tum",
    max_dt: float = 0.02,
    rpe_delta: int = 1,
    plot: str | Path | None = None,
) -> EvalReport:
    """Read both files in format ``fmt`` (tum | kitti), :func:`evaluate`, and optionally write a PNG plot."""
    gt_traj = read_trajectory(gt, fmt)
    est_traj = read_trajectory(est, fmt)
    report = evaluate(gt_traj, est_traj, align, max_dt, rpe_delta, gt_name=str(gt), est_name=str(est))
    if plot is not None:
        from gsslam.viz.plots import plot_trajectory  # matplotlib only when a plot is asked for

        assoc = report.association
        est_xyz = report.ate.alignment.apply_positions(est_traj.positions[assoc.est_indices])
        plot_trajectory(
            plot,
            gt_traj.timestamps[assoc.gt_indices],
            gt_traj.positions[assoc.gt_indices],
            est_xyz,
            title=f"{Path(est).name} vs {Path(gt).name}: ATE rmse {report.ate.stats.rmse:.4f} m ({align})",
        )
    return report
