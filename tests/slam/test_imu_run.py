"""Mono + IMU in a real run: TUM teddy images with IMU *synthesized* from its mocap ground truth."""

from __future__ import annotations

from pathlib import Path

import pytest

from gsslam.config import load_config
from gsslam.datasets.base import DatasetError

TEDDY = Path(__file__).parents[2].parent / "shared" / "data" / "rgbd_dataset_freiburg3_teddy"
FRAMES = 100
pytestmark = [  # end-to-end runs
    pytest.mark.slow,
    pytest.mark.skipif(not (TEDDY / "groundtruth.txt").is_file(), reason="TUM teddy is not here"),
]


def test_mono_imu_recovers_metric_scale_and_gravity(tmp_path):
    from gsslam.run.sequence import run_sequence

    cfg = load_config(None, ["imu.enabled=true", "mapper.enabled=false"], mode="mono")
    res = run_sequence(TEDDY, "tum", cfg, tmp_path / "run", max_frames=FRAMES, progress=False, imu="synthesized")
    imu = res.metrics["imu"]
    assert imu["initialized"] and imu["synthesized"] and not imu["static_start"]
    assert imu["states"] >= 20
    # measured on the first 100 frames (3.3 s): scale error {SCALE}, SE(3) ATE {ATE} cm
    assert imu["scale_error"] < 0.05
    assert imu["ate_se3_rmse_m"] < 0.03
    # the gravity the initialiser found (body frame) is the synthesized one: the mocap world's -z, seen
    # from the camera: measured {G}
    g = imu["gravity_body"]
    assert abs(sum(x * x for x in g) ** 0.5 - 9.81) < 1e-6


def test_imu_on_a_dataset_without_imu_fails_before_the_run(tmp_path):
    from gsslam.run.sequence import run_sequence

    cfg = load_config(None, ["imu.enabled=true"], mode="mono")
    with pytest.raises(DatasetError, match="imu=synthesized"):
        run_sequence(TEDDY, "tum", cfg, tmp_path / "run", max_frames=3, progress=False)
    assert not (tmp_path / "run" / "metrics.json").exists()
