"""Swapping other sensors into the graph: IMU + GPS and stereo VO, built from gtsam's own factors.

A runnable example (not part of the library): ``python examples/swap_in_sensors.py imu`` or
``... stereo`` prints how far each run ends from its reference.

Both examples run on the real data shipped in the gtsam wheel (``gtsam/Data``, found with
``gtsam.findExampleDataFile``) and go through :class:`gsslam.graph.backend.Backend` exactly like our
own factors do: each step buffers only its new factors and values, then calls ``update()``. They are
exercised by ``tests/graph/test_swap_in_*.py`` (which load this file by path) and quoted in docs/graph.md.

- :func:`run_kitti_imu_gps`: KITTI IMU (100 Hz) preintegrated between 1 Hz GPS epochs
  (``ImuFactor`` + ``BetweenFactorConstantBias`` + ``GPSFactor``). Poses ``X(k) = T_nav_body``
  (gtsam Pose3, navigation frame z up), velocities ``v{k}``, biases ``b{k}``.
- :func:`run_stereo_vo`: KITTI stereo VO (``GenericStereoFactor3D`` with ``Cal3_S2Stereo``), poses
  ``X(k) = T_world_cam`` (OpenCV axes), landmarks ``l{j}`` in world coordinates (metres).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import gtsam
import numpy as np

from gsslam.errors import GsslamError
from gsslam.graph.backend import Backend
from gsslam.graph.keys import keyframe_key, user_key

log = logging.getLogger(__name__)

GRAVITY = 9.8  # m/s^2, the value the KITTI IMU example data was made with


class ExampleDataError(GsslamError):
    """An example data file of the gtsam wheel is missing or malformed."""


def example_file(name: str) -> Path:
    """Path of ``name`` in gtsam's example data folder."""
    try:
        return Path(gtsam.findExampleDataFile(name))
    except (FileNotFoundError, RuntimeError, ValueError) as e:
        raise ExampleDataError(
            f"gtsam example data file {name!r} not found; install a gtsam wheel that ships gtsam/Data"
        ) from e


def _table(name: str, delimiter: str | None, skip_header: int) -> np.ndarray:
    path = example_file(name)
    try:
        return np.loadtxt(path, delimiter=delimiter, skiprows=skip_header, ndmin=2)
    except ValueError as e:
        raise ExampleDataError(f"{path}: {e}") from e


# -- IMU + GPS (KITTI) ----------------------------------------------------------------------------
@dataclass(frozen=True)
class KittiImuGps:
    """The KITTI IMU/GPS example data (IMU frame = body frame in this data)."""

    imu_time: np.ndarray  # [M] s
    imu_dt: np.ndarray  # [M] s since the previous sample
    acc: np.ndarray  # [M, 3] m/s^2, specific force in the body frame
    gyro: np.ndarray  # [M, 3] rad/s
    gps_time: np.ndarray  # [G] s
    gps_xyz: np.ndarray  # [G, 3] m, navigation frame (z up)
    acc_sigma: float  # continuous-time white noise densities from the metadata file
    gyro_sigma: float
    integration_sigma: float
    acc_bias_sigma: float  # bias random walk per IMU sample
    gyro_bias_sigma: float


def load_kitti_imu_gps() -> KittiImuGps:
    meta = _table("KittiEquivBiasedImu_metadata.txt", None, 1)[0]
    if np.any(meta[:6] != 0):
        raise ExampleDataError("the KITTI example expects the IMU frame to be the body frame")
    imu = _table("KittiEquivBiasedImu.txt", None, 1)
    gps = _table("KittiGps_converted.txt", ",", 1)
    return KittiImuGps(
        imu[:, 0],
        imu[:, 1],
        imu[:, 2:5],
        imu[:, 5:8],
        gps[:, 0],
        gps[:, 1:4],
        acc_sigma=meta[6],
        gyro_sigma=meta[7],
        integration_sigma=meta[8],
        acc_bias_sigma=meta[9],
        gyro_bias_sigma=meta[10],
    )


def imu_params(data: KittiImuGps) -> gtsam.PreintegrationParams:
    p = gtsam.PreintegrationParams.MakeSharedU(GRAVITY)  # navigation frame z up
    p.setAccelerometerCovariance(np.eye(3) * data.acc_sigma**2)
    p.setGyroscopeCovariance(np.eye(3) * data.gyro_sigma**2)
    p.setIntegrationCovariance(np.eye(3) * max(data.integration_sigma, 1e-4) ** 2)
    return p


def preintegrate(
    data: KittiImuGps, t0: float, t1: float, bias: gtsam.imuBias.ConstantBias
) -> tuple[gtsam.PreintegratedImuMeasurements, int]:
    """IMU samples with ``t0 < time <= t1`` preintegrated at ``bias``; returns (pim, sample count)."""
    pim = gtsam.PreintegratedImuMeasurements(imu_params(data), bias)
    sel = np.flatnonzero((data.imu_time > t0) & (data.imu_time <= t1))
    for j in sel:
        pim.integrateMeasurement(data.acc[j], data.gyro[j], data.imu_dt[j])
    return pim, len(sel)


@dataclass
class ImuGpsResult:
    backend: Backend
    epochs: np.ndarray  # [E] GPS indices, one state per epoch
    used_gps: np.ndarray  # [E] bool, whether that epoch got a GPS factor
    positions: np.ndarray  # [E, 3] m, optimized positions after the last update
    imu_only: np.ndarray  # [E, 3] m, position at epoch k predicted by the IMU from the estimate at k-1


def run_kitti_imu_gps(
    data: KittiImuGps,
    first: int = 1,
    count: int = 100,
    gps_every: int = 1,
    gps_sigma: float = 0.3,
    backend: Backend | None = None,
) -> ImuGpsResult:
    """Incremental IMU + GPS fusion over GPS epochs ``first .. first + count - 1``.

    One state (pose, velocity, bias) per GPS epoch; consecutive states are linked by an ImuFactor over
    the preintegrated IMU samples and a bias random walk. Every ``gps_every``-th epoch gets a
    GPSFactor (``gps_sigma`` m). The initial heading and velocity come from the first two GPS fixes.
    One ``Backend.update()`` per epoch, with only that epoch's factors and values.
    """
    if count < 3 or first + count > len(data.gps_time):
        raise ExampleDataError(f"need 3 <= count and first + count <= {len(data.gps_time)} GPS epochs")
    be = backend if backend is not None else Backend()
    X, V, B = keyframe_key, (lambda k: user_key("v", k)), (lambda k: user_key("b", k))
    gps_noise = gtsam.noiseModel.Isotropic.Sigma(3, gps_sigma)
    epochs = np.arange(first, first + count)
    used = (epochs - first) % gps_every == 0
    imu_only = np.full((count, 3), np.nan)

    d = data.gps_xyz[first + 1] - data.gps_xyz[first]
    vel0 = d / (data.gps_time[first + 1] - data.gps_time[first])
    pose0 = gtsam.Pose3(gtsam.Rot3.Yaw(np.arctan2(d[1], d[0])), data.gps_xyz[first])
    bias0 = gtsam.imuBias.ConstantBias()
    be.add_value(X(0), pose0)
    be.add_value(V(0), vel0)
    be.add_value(B(0), bias0)
    sig_rp, sig_yaw = 0.05, 0.3  # rad: the car starts about level, heading from two GPS fixes
    be.add_factor(
        gtsam.PriorFactorPose3(
            X(0), pose0, gtsam.noiseModel.Diagonal.Sigmas(np.array([sig_rp, sig_rp, sig_yaw, 1.0, 1.0, 1.0]))
        )
    )
    be.add_factor(gtsam.PriorFactorVector(V(0), vel0, gtsam.noiseModel.Isotropic.Sigma(3, 2.0)))
    be.add_factor(
        gtsam.PriorFactorConstantBias(
            B(0), bias0, gtsam.noiseModel.Diagonal.Sigmas(np.array([0.1] * 3 + [5e-5] * 3))
        )
    )
    be.add_factor(gtsam.GPSFactor(X(0), data.gps_xyz[first], gps_noise))
    be.update()

    for k in range(1, count):
        g0, g1 = epochs[k - 1], epochs[k]
        bias = be.estimate(B(k - 1))
        pim, n = preintegrate(data, data.gps_time[g0], data.gps_time[g1], bias)
        if n == 0:
            raise ExampleDataError(f"no IMU samples between GPS epochs {g0} and {g1}")
        pred = pim.predict(gtsam.NavState(be.estimate(X(k - 1)), be.estimate(V(k - 1))), bias)
        imu_only[k] = pred.position()
        be.add_value(X(k), pred.pose())
        be.add_value(V(k), pred.velocity())
        be.add_value(B(k), bias)
        be.add_factor(gtsam.ImuFactor(X(k - 1), V(k - 1), X(k), V(k), B(k - 1), pim))
        walk = np.sqrt(n) * np.array([data.acc_bias_sigma] * 3 + [data.gyro_bias_sigma] * 3)
        be.add_factor(
            gtsam.BetweenFactorConstantBias(
                B(k - 1), B(k), gtsam.imuBias.ConstantBias(), gtsam.noiseModel.Diagonal.Sigmas(walk)
            )
        )
        if used[k]:
            be.add_factor(gtsam.GPSFactor(X(k), data.gps_xyz[g1], gps_noise))
        be.update()

    vals = be.values()
    positions = np.array([vals.atPose3(X(k)).translation() for k in range(count)])
    return ImuGpsResult(be, epochs, used, positions, imu_only)


# -- stereo VO (KITTI) ----------------------------------------------------------------------------
@dataclass(frozen=True)
class StereoVO:
    """gtsam's KITTI stereo VO example: camera poses, stereo measurements, calibration."""

    calib: gtsam.Cal3_S2Stereo  # fx, fy, skew, cx, cy, baseline (m)
    pose_ids: np.ndarray  # [P] int
    T_world_cam: np.ndarray  # [P, 4, 4] the VO poses of the file
    obs: np.ndarray  # [M, 8] pose id, landmark id, uL, uR, v (px), X, Y, Z (m, in that camera's frame)


def load_stereo_vo(variant: str = "_large") -> StereoVO:
    """``variant``: ``"_large"`` (25 poses, 8188 measurements), ``"00s"`` or ``"00"``."""
    cal_name = "VO_calibration.txt" if variant == "_large" else f"VO_calibration{variant}.txt"
    try:
        cal = np.array(example_file(cal_name).read_text().split(), dtype=np.float64)
    except ValueError as e:
        raise ExampleDataError(f"{cal_name}: {e}") from e
    poses = _table(f"VO_camera_poses{variant}.txt", None, 0)
    obs = _table(f"VO_stereo_factors{variant}.txt", None, 0)
    if cal.shape != (6,) or poses.shape[1] != 17 or obs.shape[1] != 8:
        raise ExampleDataError(f"unexpected layout of the VO{variant} example files")
    return StereoVO(gtsam.Cal3_S2Stereo(*cal), poses[:, 0].astype(int), poses[:, 1:].reshape(-1, 4, 4), obs)


def perturb_poses(T: np.ndarray, rot_sigma: float, trans_sigma: float, seed: int) -> np.ndarray:
    """``T`` [P, 4, 4] times a random right perturbation (rad, m); the first pose is kept."""
    rng = np.random.default_rng(seed)
    out = T.copy()
    for k in range(1, len(T)):
        xi = np.concatenate([rng.normal(0, rot_sigma, 3), rng.normal(0, trans_sigma, 3)])
        out[k] = T[k] @ gtsam.Pose3.Expmap(xi).matrix()
    return out


def run_stereo_vo(
    data: StereoVO,
    T_init: np.ndarray,  # [P, 4, 4] initial T_world_cam (e.g. perturbed VO poses)
    pixel_sigma: float = 1.0,
    backend: Backend | None = None,
) -> tuple[Backend, gtsam.Values]:
    """Incremental stereo bundle adjustment, one ``Backend.update()`` per camera.

    Camera ``k`` adds its pose ``X(pose_id)`` (from ``T_init``), one ``GenericStereoFactor3D`` per
    measurement, and the landmarks it sees first, back-projected from ``T_init``. The first pose is
    held fixed (the gauge) by a tight prior. Robust (Huber) pixel noise absorbs bad matches.
    Returns the backend and the initial values it was given.
    """
    be = backend if backend is not None else Backend()
    X, L = keyframe_key, (lambda j: user_key("l", j))
    initial = gtsam.Values()
    noise = gtsam.noiseModel.Robust.Create(
        gtsam.noiseModel.mEstimator.Huber.Create(1.345),
        gtsam.noiseModel.Isotropic.Sigma(3, pixel_sigma),
    )
    for k, pid in enumerate(data.pose_ids):
        pose = gtsam.Pose3(T_init[k])
        be.add_value(X(pid), pose)
        initial.insert(X(pid), pose)
        if k == 0:
            be.add_factor(gtsam.PriorFactorPose3(X(pid), pose, gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
        for row in data.obs[data.obs[:, 0] == pid]:
            lid = int(row[1])
            if not be.has_value(L(lid)):
                be.add_value(L(lid), pose.transformFrom(row[5:8]))
                initial.insert(L(lid), pose.transformFrom(row[5:8]))
            be.add_factor(
                gtsam.GenericStereoFactor3D(gtsam.StereoPoint2(*row[2:5]), noise, X(pid), L(lid), data.calib)
            )
        be.update()
    return be, initial


def main(argv: list[str] | None = None) -> None:
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("demo", choices=["imu", "stereo"])
    args = ap.parse_args(argv)
    if args.demo == "imu":
        data = load_kitti_imu_gps()
        res = run_kitti_imu_gps(data, count=150)
        err = np.linalg.norm(res.positions - data.gps_xyz[res.epochs], axis=1)
        print(f"IMU+GPS over {len(err)} GPS epochs: position vs GPS RMSE {np.sqrt(np.mean(err**2)):.2f} m")
    else:
        data = load_stereo_vo()
        be, initial = run_stereo_vo(data, perturb_poses(data.T_world_cam, 0.02, 0.2, seed=0))
        vals = be.values()
        err = [
            np.linalg.norm(vals.atPose3(keyframe_key(int(p))).translation() - data.T_world_cam[k][:3, 3])
            for k, p in enumerate(data.pose_ids)
        ]
        print(f"stereo VO over {len(err)} cameras: mean distance to the file's VO poses {np.mean(err):.3f} m")


if __name__ == "__main__":
    main()
