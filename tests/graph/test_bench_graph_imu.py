"""`gsslam bench graph --imu`: the IMU chain is consistent (it helps, not hurts, the estimate)."""

from __future__ import annotations

import pytest

from gsslam.bench.graph import run_one
from gsslam.config import GraphConfig

pytestmark = pytest.mark.slow  # two 30-keyframe bench graphs (~40 s on 2 shared cores)


def test_imu_factors_join_the_bench_graph_and_keep_it_accurate():
    r = run_one(30, 60, GraphConfig(), imu=True)
    no_imu = run_one(30, 60, GraphConfig(), imu=False)
    # per keyframe: a CombinedImuFactor (+ the priors on v0, b0)
    assert r["factors"] == no_imu["factors"] + 29 + 2
    # synthesized IMU consistent with the trajectory: not worse than flow alone (measured 2.3 vs 8.7 cm
    # at 60 keyframes / 200 points)
    assert r["isam2_position_error_max_m"] < max(0.05, 1.5 * no_imu["isam2_position_error_max_m"])
    # the IMU's cost is in iSAM2: velocities and biases make each update relinearise and re-eliminate
    # more variables (measured at 30 keyframes: 24.7 / 38.5 vs 3.6 / 6.1; at 800: 12.4 / 28.0 vs 6.3 / 12.1)
    assert r["isam2_reeliminated_mean"] > 2 * no_imu["isam2_reeliminated_mean"]
