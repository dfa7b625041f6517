"""Mono + IMU in a real run: TUM teddy images with IMU *synthesized* from its mocap ground truth."""

from __future__ import annotations

from pathlib import Path

import pytest

from gsslam.config import load_config
from gsslam.datasets.base import DatasetError

TEDDY = Path(__file__).parents[2].parent / "shared" / "data" / "rgbd_dataset_freiburg3_teddy"
FRAMES = 200  # all of teddy-200: on 100 frames (3.3 s) the scale error was 27 % (measured)
pytestmark = [  # end-to-end runs
    pytest.mark.slow,
    pytest.mark.skipif(not (TEDDY / "groundtruth.txt").is_file(), reason="TUM teddy is not here"),
]


def test_mono_imu_gives_metric_scale_on_teddy_200(tmp_path):
    from gsslam.run.sequence import run_sequence

    cfg = load_config(None, ["imu.enabled=true", "mapper.enabled=false"], mode="mono")
    res = run_sequence(
        TEDDY, "tum", cfg, tmp_path / "run", max_frames=FRAMES, progress=False, imu="synthesized"
    )
    imu = res.metrics["imu"]
    assert imu["initialized"] and imu["synthesized"] and not imu["static_start"]
    assert imu["states"] >= 50  # measured 59 (61 keyframes, the first before the mocap starts)
    # measured (defaults, session 5: the tie in submap units): scale error 1.73 %, SE(3) ATE 1.47 cm
    # (before: 5.7 %, 3.20 cm; mono alone: 15 % arbitrary, 9.89 cm). The targets: 2 %, 2 cm.
    assert imu["scale_error"] < 0.025
    assert imu["ate_se3_rmse_m"] < 0.02
    assert imu["ate_sim3_rmse_m"] < 0.015  # measured 1.13 cm (mono alone 1.20 cm)


def test_imu_on_a_dataset_without_imu_fails_before_the_run(tmp_path):
    from gsslam.run.sequence import run_sequence

    cfg = load_config(None, ["imu.enabled=true"], mode="mono")
    with pytest.raises(DatasetError, match="imu=synthesized"):
        run_sequence(TEDDY, "tum", cfg, tmp_path / "run", max_frames=3, progress=False)
    assert not (tmp_path / "run" / "metrics.json").exists()
