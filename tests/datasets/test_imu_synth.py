"""IMU synthesized from TUM teddy's mocap ground truth: integrating it reproduces the trajectory."""

from __future__ import annotations

from pathlib import Path

import gtsam
import numpy as np
import pytest

from gsslam.config import ImuConfig
from gsslam.datasets.imu_synth import EUROC_IMU_NOISE, synthesize_imu
from gsslam.graph.imu import preintegrate, preintegration_params

TEDDY = Path(__file__).parents[2].parent / "shared" / "data" / "rgbd_dataset_freiburg3_teddy"
pytestmark = pytest.mark.skipif(not (TEDDY / "groundtruth.txt").is_file(), reason="TUM teddy is not here")


@pytest.fixture(scope="module")
def gt():
    from gsslam.io.trajectory import read_tum

    return read_tum(TEDDY / "groundtruth.txt")


def _integrate_1s(syn, a: int, b: int):
    """Predict sample b's pose from sample a's spline state with the synthesized IMU in between."""
    s = syn.samples
    pim = preintegrate(
        s.timestamps, s.gyro, s.accel, s.timestamps[a], s.timestamps[b], gtsam.imuBias.ConstantBias(),
        preintegration_params(ImuConfig()),
    )  # fmt: skip
    st = gtsam.NavState(gtsam.Rot3(syn.R_world_body[a]), syn.p_world_body[a], syn.v_world_body[a])
    return pim.predict(st, gtsam.imuBias.ConstantBias())


@pytest.mark.parametrize("noise", ["euroc", "none"])
def test_integrating_synthesized_imu_reproduces_ground_truth(gt, noise):
    t0 = gt.timestamps[0] + 0.5
    nz = EUROC_IMU_NOISE if noise == "euroc" else dict.fromkeys(EUROC_IMU_NOISE, 0.0)
    syn = synthesize_imu(gt.timestamps, gt.poses, noise=nz, seed=3, t_range=(t0, t0 + 4.0), smoothing=1e-4)
    s = syn.samples
    assert s.synthesized and len(s) == pytest.approx(800, abs=2)  # 200 Hz over 4 s
    assert np.allclose(np.diff(s.timestamps), 0.005, atol=1e-6)  # float64 seconds since 1970
    # the spline goes near the mocap poses (lam 1e-4, measured over 8 s: median 0.27 mm, max 2.5 mm)
    m = (gt.timestamps > s.timestamps[0]) & (gt.timestamps < s.timestamps[-1])
    p = np.stack([np.interp(gt.timestamps[m], s.timestamps, syn.p_world_body[:, k]) for k in range(3)], 1)
    assert np.median(np.linalg.norm(p - gt.poses[m, :3, 3], axis=1)) < 5e-4
    worst_p, worst_r = 0.0, 0.0
    for a in (0, 200, 400, 599):
        b = a + 200  # 1 s windows
        pred = _integrate_1s(syn, a, b)
        worst_p = max(worst_p, np.linalg.norm(pred.position() - syn.p_world_body[b]))
        dR = pred.attitude().matrix().T @ syn.R_world_body[b]
        worst_r = max(worst_r, np.linalg.norm(gtsam.Rot3.Logmap(gtsam.Rot3(dR))))
    if noise == "none":  # exact samples: only the 200 Hz discretisation is left (measured <= 0.19 mm)
        assert worst_p < 2e-3 and worst_r < 1e-3
    else:  # EuRoC noise + bias walk (measured 2-6 mm, 0.03-0.06 deg per 1 s before the midpoint change)
        assert worst_p < 0.02 and worst_r < np.radians(0.3)


def test_synthesis_is_seeded(gt):
    t0 = gt.timestamps[0] + 0.5
    a = synthesize_imu(gt.timestamps, gt.poses, seed=1, t_range=(t0, t0 + 1.0), smoothing=1e-4).samples
    b = synthesize_imu(gt.timestamps, gt.poses, seed=1, t_range=(t0, t0 + 1.0), smoothing=1e-4).samples
    c = synthesize_imu(gt.timestamps, gt.poses, seed=2, t_range=(t0, t0 + 1.0), smoothing=1e-4).samples
    assert np.array_equal(a.accel, b.accel) and not np.array_equal(a.accel, c.accel)
