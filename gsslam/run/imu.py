"""``--imu`` in a run: the IMU stage from the dataset's samples, and its numbers for ``metrics.json``.

A dataset gives an IMU through :class:`gsslam.datasets.base.ImuDataset` (``imu()`` samples and
``T_body_cam``): EuRoC ``imu0``, TUM with ``imu=synthesized`` (samples synthesized from the ground
truth; labelled so in ``metrics.json``).
"""

from __future__ import annotations

import logging

from gsslam.config import Config
from gsslam.datasets.base import DatasetError, ImuDataset
from gsslam.errors import GsslamError

log = logging.getLogger(__name__)


def make_imu_stage(cfg: Config, ds):
    """The :class:`gsslam.slam.imu_stage.ImuStage` for ``ds``; raises when the dataset has no IMU."""
    from gsslam.slam.imu_stage import ImuStage

    if not isinstance(ds, ImuDataset):
        raise DatasetError(
            f"--imu: the {type(ds).__name__} loader gives no IMU samples "
            "(EuRoC has imu0; TUM needs --dataset-arg imu=synthesized)"
        )
    return ImuStage(cfg, ds.imu(), ds.T_body_cam)


def imu_metrics(stage, pipe, gt) -> dict:
    """The initialisation, final biases, and (with ground truth) ATE with SE(3) alignment + scale."""
    from gsslam.eval.ate import compute_ate
    from gsslam.run.outputs import trajectory_of

    out = dict(stage.report)
    out["synthesized"] = bool(stage.samples.synthesized)  # made from ground truth, not measured
    try:
        if pipe.chains and stage.chain is not None:
            out.update(stage.estimates(pipe.chains[0].graph))
        traj = trajectory_of(pipe, pipe.frame_poses())
    except GsslamError as e:  # an interrupted run: keep what there is
        log.warning("IMU metrics: %s", e)
        return out
    if gt is not None and len(traj) >= 3 and len(pipe.chains) == 1:
        try:
            se3, _ = compute_ate(gt, traj, align="se3")
            sim3, _ = compute_ate(gt, traj, align="sim3")
            out["ate_se3_rmse_m"] = float(se3.stats.rmse)
            out["ate_sim3_rmse_m"] = float(sim3.stats.rmse)
            out["sim3_scale"] = float(sim3.alignment.scale)
            out["scale_error"] = float(abs(sim3.alignment.scale - 1.0))  # gt = s R est + t
        except Exception as e:  # noqa: BLE001 - numbers must never lose the run
            log.warning("IMU metrics: no ATE: %s", e)
    return out
