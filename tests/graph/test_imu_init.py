"""IMU initialisation on real EuRoC imu0 (static prefix) and on synthesized IMU (TUM teddy ground truth)."""

from __future__ import annotations

from pathlib import Path

import gtsam
import numpy as np
import pytest

from gsslam.config import ImuConfig
from gsslam.graph.backend import Backend
from gsslam.graph.imu import (
    B,
    ImuChain,
    V,
    is_static,
    preintegration_params,
    static_init,
    visual_inertial_init,
)
from gsslam.graph.keys import keyframe_key

REPO = Path(__file__).parents[2]
EUROC = [REPO / "data" / "euroc_V1_01_easy_20", REPO.parent / "shared" / "data" / "euroc_V1_01_easy"]
TEDDY = REPO.parent / "shared" / "data" / "rgbd_dataset_freiburg3_teddy"


def _euroc_imu(path: Path):
    from gsslam.datasets.euroc import EurocDataset

    if not (path / "mav0" / "imu0" / "data.csv").is_file():
        pytest.skip(f"{path} is not here")
    return EurocDataset(path).imu()


@pytest.mark.parametrize("path", EUROC, ids=["bundled", "shared"])
def test_static_init_on_euroc_prefix(path):
    s = _euroc_imu(path)
    cfg = ImuConfig()
    # the MAV rests with its rotors running: per-sample std 0.2-1.0 m/s^2, of 0.1 s means <= 0.102 (measured)
    assert is_static(s.timestamps, s.accel, cfg.static_max_accel_std)
    init = static_init(s.gyro, s.accel, cfg.gravity)
    g = np.linalg.norm(init.gravity_body)
    assert 9.7 < g < 9.9  # measured 9.779 (shared, 4.8 s) / 9.781 (bundled, 1.05 s)
    assert np.linalg.norm(init.accel_bias) < 0.1  # |mean accel| - g: measured 0.031 / 0.029 m/s^2
    # measured gyro bias (-0.0020, 0.0208, 0.0781) rad/s on both prefixes (EuRoC's own ground-truth
    # estimate for V1_01 starts near (-0.002, 0.021, 0.076))
    np.testing.assert_allclose(init.gyro_bias, [-0.002, 0.021, 0.078], atol=0.005)
    # the world's z is up: the rotated mean specific force points along +z with norm g
    np.testing.assert_allclose(init.R_world_body @ -init.gravity_body, [0, 0, g], atol=1e-9)


def test_imu_chain_on_the_static_euroc_prefix_does_not_diverge():
    s = _euroc_imu(EUROC[1])
    cfg = ImuConfig()
    init = static_init(s.gyro, s.accel, cfg.gravity)
    be = Backend()
    chain = ImuChain(be, cfg, s.timestamps, s.gyro, s.accel)
    times = np.arange(s.timestamps[0], s.timestamps[-1] - 1e-3, 0.25)  # a keyframe every 0.25 s
    bias = gtsam.imuBias.ConstantBias(init.accel_bias, init.gyro_bias)
    X0 = np.eye(4)
    X0[:3, :3] = init.R_world_body
    chain.start(0, times[0], X0, np.zeros(3), bias, velocity_sigma=0.01)
    prior = gtsam.noiseModel.Isotropic.Sigma(6, 1e-3)
    be.add_factor(gtsam.PriorFactorPose3(keyframe_key(0), gtsam.Pose3(X0), prior))
    be.update()
    for k in range(1, len(times)):
        chain.add(k, times[k])
        be.update()
    n = len(times) - 1
    p = be.estimate(keyframe_key(n)).translation()
    v = be.estimate(V(n))
    b = be.estimate(B(n))
    # IMU only, 4.5 s at rest (rotors running): measured end drift 0.024 m, speed 0.031 m/s; the biases
    # stay at the initial estimate (nothing else observes them)
    assert np.linalg.norm(p) < 0.05
    assert np.linalg.norm(v) < 0.05
    assert np.linalg.norm(b.gyroscope() - init.gyro_bias) < 0.01
    assert np.linalg.norm(b.accelerometer() - init.accel_bias) < 0.05


@pytest.mark.skipif(not (TEDDY / "groundtruth.txt").is_file(), reason="TUM teddy is not here")
def test_visual_inertial_init_recovers_scale_from_ground_truth_poses():
    """Keyframe poses = teddy ground truth shrunk to 0.5 (a monocular scale); IMU synthesized from it."""
    from gsslam.datasets.tum import TumRgbdDataset

    ds = TumRgbdDataset(TEDDY, with_depth=False, imu="synthesized")
    s = ds.imu()
    frames = list(range(6, 80, 4))  # 19 keyframes over 2.5 s
    times = np.array([ds.timestamps()[i] for i in frames])
    T = np.stack([ds[i].T_world_cam_gt for i in frames])
    T = np.linalg.inv(T[0]) @ T  # the first camera is the visual world
    T[:, :3, 3] *= 0.5
    init = visual_inertial_init(
        times, T, np.eye(4), s.timestamps, s.gyro, s.accel, preintegration_params(ImuConfig()), 9.81
    )
    # measured 1.950 (the nearest-row ground truth is up to 10 ms off the image times: errors in the
    # regressor pull a least-squares scale low); 5 keyframes gave 1.71, 10 gave 1.89
    assert abs(init.scale / 2.0 - 1) < 0.05
    assert np.linalg.norm(init.gyro_bias) < 0.005  # the synthesized bias starts at 0; measured 0.0017
