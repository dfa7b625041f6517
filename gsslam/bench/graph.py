"""``gsslam bench graph``: iSAM2 update time per keyframe and batch LM time on a synthetic chain.

Keyframes (Pose3) move on a circle inside a cylinder, in laps of 100; each new keyframe gets one batched
flow factor (``points`` matches) from each of its 2 predecessors, and every ``loop_every``-th keyframe
of the second lap a flow factor to the keyframe one lap earlier (a loop). Times are wall-clock on
this machine; nothing is asserted (speed is reported, never tested). Each result also carries
``reference_ms``, a fixed numpy workload shaped like one flow factor's linearisation (1000 points
projected, their 2x6 Jacobians built and reduced), timed in the same process just before and after
the size: ``isam2_update_median_per_reference`` compares machines and days (the absolute
milliseconds say as much about the machine and its load as about the graph). On a shared machine the
process's CPU time per update (``isam2_update_cpu_ms_*``, ``time.process_time``) moves much less with
the other jobs than wall time; ``isam2_relinearized_mean`` / ``isam2_reeliminated_mean`` count the
variables iSAM2 relinearised / re-eliminated per update.

With ``imu=True`` each keyframe also gets a velocity ``v`` and an IMU bias ``b`` and a
``CombinedImuFactor`` to its predecessor (keyframes 0.1 s apart, 200 Hz IMU SYNTHESIZED from the
bench trajectory by finite differences, EuRoC imu0 noise densities; gravity along -z).
"""

from __future__ import annotations

import statistics
import time

import gtsam
import numpy as np

from gsslam.config import GraphConfig
from gsslam.factors import make_flow_factor
from gsslam.graph.backend import Backend
from gsslam.graph.keys import keyframe_key, user_key

_K = np.array([[300.0, 0, 160], [0, 300.0, 120], [0, 0, 1]])
_W, _H = 320, 240
_REPORTED = (
    "relinearize_threshold",
    "relinearize_threshold_velocity",
    "relinearize_threshold_bias",
    "relinearize_skip",
    "wildfire_threshold",
)


def _pose(k: int, per_lap: int) -> np.ndarray:
    th = 2 * np.pi * k / per_lap
    T = np.eye(4)
    z = np.array([np.cos(th + 0.3), 0.0, np.sin(th + 0.3)])
    y = np.array([0.0, 1.0, 0.0])
    T[:3, :3] = np.stack([np.cross(y, z), y, z], axis=1)
    T[:3, 3] = [5 * np.cos(th), 0.1 * np.sin(7 * th), 5 * np.sin(th)]
    return T


def _matches(Ta, Tb, n, rng):
    """n flow matches a -> b from ray-casting a cylinder of radius 10 (1 px noise, 5 % outliers)."""
    uv = rng.uniform([0, 0], [_W, _H], (4 * n, 2))
    rays = np.c_[(uv - _K[:2, 2]) / _K[[0, 1], [0, 1]], np.ones(len(uv))]
    d, c = rays @ Ta[:3, :3].T, Ta[:3, 3]
    a = d[:, 0] ** 2 + d[:, 2] ** 2
    b = 2 * (c[0] * d[:, 0] + c[2] * d[:, 2])
    t = (-b + np.sqrt(b * b - 4 * a * (c[0] ** 2 + c[2] ** 2 - 100.0))) / (2 * a)
    Xw = c + d * t[:, None]
    Tbi = np.linalg.inv(Tb)
    Xb = Xw @ Tbi[:3, :3].T + Tbi[:3, 3]
    uvb = Xb[:, :2] / Xb[:, 2:] * _K[[0, 1], [0, 1]] + _K[:2, 2]
    ok = (Xb[:, 2] > 0.1) & (uvb[:, 0] >= 0) & (uvb[:, 0] < _W) & (uvb[:, 1] >= 0) & (uvb[:, 1] < _H)
    idx = np.flatnonzero(ok)[:n]
    uvb = uvb[idx] + rng.normal(scale=1.0, size=(len(idx), 2))
    out = rng.random(len(idx)) < 0.05
    uvb[out] += rng.uniform(-40, 40, (out.sum(), 2))
    return uv[idx], t[idx], uvb


def reference_ms(repeats: int = 15) -> float:
    """Median milliseconds of a fixed numpy workload like one flow-factor linearisation (see above)."""
    rng = np.random.default_rng(0)
    p = rng.normal(size=(1000, 3)) + [0, 0, 3]
    R, t = np.eye(3), np.array([0.1, 0, 0])
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(10):
            q = p @ R.T + t
            z = q[:, 2:3]
            uv = q[:, :2] / z * 300.0 + 160.0
            J = np.zeros((len(q), 2, 6))
            J[:, 0, 3], J[:, 1, 4] = 300.0 / z[:, 0], 300.0 / z[:, 0]
            J[:, :, 5] = -(uv - 160.0) / z
            J[:, 0, :3] = np.cross(q, [1.0, 0, 0]) * 300.0 / z
            J[:, 1, :3] = np.cross(q, [0, 1.0, 0]) * 300.0 / z
            np.einsum("nij,nik->jk", J, J)
        times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times)


# EuRoC imu0/sensor.yaml (ADIS16448): continuous-time noise densities and random walks
_GYRO_NOISE, _ACC_NOISE, _GYRO_WALK, _ACC_WALK = 1.6968e-4, 2.0e-3, 1.9393e-5, 3.0e-3
_KF_DT, _IMU_RATE = 0.1, 200


def _pose_at(u: float, per_lap: int) -> np.ndarray:  # u: keyframe index, continuous
    return _pose(u, per_lap)  # type: ignore[arg-type]


def _imu_params() -> gtsam.PreintegrationCombinedParams:
    """The run's parameters (``gsslam.graph.imu``, default ``imu.*`` config = EuRoC imu0 densities)."""
    from gsslam.config import ImuConfig
    from gsslam.graph.imu import preintegration_params

    return preintegration_params(ImuConfig())


def _velocity(u: float, per_lap: int) -> np.ndarray:
    h = 1e-4
    return (_pose_at(u + h, per_lap)[:3, 3] - _pose_at(u - h, per_lap)[:3, 3]) / (2 * h * _KF_DT)


def _preintegrate(k: int, per_lap: int, params, rng) -> gtsam.PreintegratedCombinedMeasurements:
    """IMU samples between keyframes k-1 and k, synthesized from the trajectory (+ white noise)."""
    pim = gtsam.PreintegratedCombinedMeasurements(params, gtsam.imuBias.ConstantBias())
    n = int(round(_KF_DT * _IMU_RATE))
    dt = 1.0 / _IMU_RATE
    h = 1e-3  # in keyframe units
    g = np.array([0.0, 0.0, -9.81])
    for i in range(n):
        u = k - 1 + (i + 0.5) / n
        T0, T1, Tm = _pose_at(u, per_lap), _pose_at(u + h, per_lap), _pose_at(u - h, per_lap)
        w = np.asarray(gtsam.Rot3.Logmap(gtsam.Rot3(T0[:3, :3].T @ T1[:3, :3]))) / (h * _KF_DT)
        a_world = (T1[:3, 3] - 2 * T0[:3, 3] + Tm[:3, 3]) / (h * _KF_DT) ** 2
        f = T0[:3, :3].T @ (a_world - g)
        w = w + rng.normal(scale=_GYRO_NOISE / np.sqrt(dt), size=3)
        f = f + rng.normal(scale=_ACC_NOISE / np.sqrt(dt), size=3)
        pim.integrateMeasurement(f, w, dt)
    return pim


def run_one(
    n: int, points: int, cfg: GraphConfig, loop_every: int = 50, seed: int = 0, imu: bool = False
) -> dict:
    ref0 = reference_ms()
    rng = np.random.default_rng(seed)
    per_lap = 100  # keyframes 3.6 degrees apart; later laps loop back to earlier ones
    truth = [_pose(k, per_lap) for k in range(n)]
    V, B = (lambda k: user_key("v", k)), (lambda k: user_key("b", k))
    imu_params = _imu_params() if imu else None
    backend = Backend.from_config(cfg)  # iSAM2 parameters and per-character relinearisation thresholds
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.full(6, 1e-4))
    times, loops = [], 0
    cpu, relin, reelim = [], [], []  # process CPU seconds and iSAM2 counts per update
    for k in range(n):
        # like a tracking frontend: previous estimate composed with a noisy relative motion
        rel = gtsam.Pose3(np.linalg.inv(truth[k - 1]) @ truth[k]) if k else gtsam.Pose3(truth[0])
        prev = backend.estimate(keyframe_key(k - 1)) if k else gtsam.Pose3()
        init = prev.compose(rel).retract(rng.normal(scale=0.003, size=6))
        backend.add_value(keyframe_key(k), init)
        if k == 0:
            backend.add_factor(gtsam.PriorFactorPose3(keyframe_key(0), gtsam.Pose3(truth[0]), noise))
        if imu:
            backend.add_value(V(k), _velocity(k, per_lap) + rng.normal(scale=0.01, size=3))
            backend.add_value(B(k), gtsam.imuBias.ConstantBias())
            if k == 0:
                backend.add_factor(
                    gtsam.PriorFactorVector(
                        V(0), _velocity(0, per_lap), gtsam.noiseModel.Isotropic.Sigma(3, 0.01)
                    )
                )
                backend.add_factor(
                    gtsam.PriorFactorConstantBias(
                        B(0), gtsam.imuBias.ConstantBias(), gtsam.noiseModel.Isotropic.Sigma(6, 0.1)
                    )
                )
            else:
                pim = _preintegrate(k, per_lap, imu_params, rng)
                backend.add_factor(
                    gtsam.CombinedImuFactor(
                        keyframe_key(k - 1), V(k - 1), keyframe_key(k), V(k), B(k - 1), B(k), pim
                    )
                )
        pairs = [k - 1, k - 2]
        if k >= per_lap and (k - per_lap) % loop_every == loop_every - 1:
            pairs.append(k - per_lap)
            loops += 1
        for j in pairs:
            if j < 0:
                continue
            uv, dep, uvb = _matches(truth[j], truth[k], points, rng)
            backend.add_factor(
                make_flow_factor(
                    keyframe_key(j),
                    keyframe_key(k),
                    uv,
                    dep,
                    uvb,
                    _K,
                    cfg.flow_sigma_px,
                    inlier_prior=cfg.flow_inlier_prior,
                    outlier_range_px=cfg.flow_outlier_range_px,
                )
            )
        t0, c0 = time.perf_counter(), time.process_time()
        res = backend.update()
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
        if res is not None:
            relin.append(res.getVariablesRelinearized())
            reelim.append(res.getVariablesReeliminated())
    est = backend.values()
    err = [np.linalg.norm(est.atPose3(keyframe_key(k)).translation() - truth[k][:3, 3]) for k in range(n)]
    t0 = time.perf_counter()
    backend.refine_batch()
    t_batch = time.perf_counter() - t0
    ms = [1e3 * t for t in times[1:]]
    ref = 0.5 * (ref0 + reference_ms())
    return {
        "keyframes": n,
        "points_per_pair": points,
        "imu": "CombinedImuFactor per keyframe (IMU synthesized)" if imu else None,
        "factors": backend.num_factors,
        "loops": loops,
        "isam2_update_ms_median": round(statistics.median(ms), 3),
        "isam2_update_ms_p90": round(float(np.percentile(ms, 90)), 3),
        "isam2_update_ms_max": round(max(ms), 3),
        "isam2_update_cpu_ms_median": round(1e3 * statistics.median(cpu[1:]), 3),
        "isam2_update_cpu_ms_p90": round(1e3 * float(np.percentile(cpu[1:], 90)), 3),
        "isam2_relinearized_mean": round(float(np.mean(relin)), 2) if relin else None,
        "isam2_reeliminated_mean": round(float(np.mean(reelim)), 2) if reelim else None,
        "isam2_position_error_max_m": round(float(max(err)), 4),
        "batch_lm_s": round(t_batch, 3),
        "reference_ms": round(ref, 3),
        "isam2_update_median_per_reference": round(statistics.median(ms) / ref, 3),
        "batch_lm_per_reference": round(1e3 * t_batch / ref, 1),
    }


def run(sizes: list[int], points: int, cfg: GraphConfig | None = None, imu: bool = False) -> dict:
    cfg = cfg or GraphConfig()
    return {
        "config": {k: getattr(cfg, k) for k in _REPORTED},
        "results": [run_one(n, points, cfg, imu=imu) for n in sizes],
    }
