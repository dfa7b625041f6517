"""IMU in the graph: gtsam's preintegrated ``CombinedImuFactor`` between keyframe states, and initialisers.

States (one per keyframe ``f`` with IMU data): ``x{f}`` Pose3 ``T_world_body``, ``v{f}`` velocity
(world, m/s), ``b{f}`` ``imuBias.ConstantBias`` (accel, gyro). The world is z-up: gravity is
``(0, 0, -g)`` in the preintegration parameters. :class:`ImuChain` adds states and factors to a
:class:`gsslam.graph.backend.Backend` (buffered; the caller runs ``update``).

Initialisers (pure numpy + gtsam preintegration):

- :func:`static_init`: the IMU rests: gravity direction from the mean accel, gyro bias = mean gyro,
  accel bias along gravity = ``|mean accel| - g`` (its horizontal part cannot be told from a tilt).
- :func:`visual_inertial_init`: the IMU moves: scale, gravity and velocities from up-to-scale visual
  keyframe poses and the preintegrated IMU between them (linear least squares, then ``|g|`` fixed),
  gyro bias first from the visual relative rotations.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import gtsam
import numpy as np

from gsslam.config import ImuConfig
from gsslam.errors import GsslamError
from gsslam.graph.keys import keyframe_key, user_key

log = logging.getLogger(__name__)


class ImuError(GsslamError):
    """IMU samples do not cover an interval, or an initialisation is ill-posed."""


def V(f: int) -> int:
    return user_key("v", f)


def B(f: int) -> int:
    return user_key("b", f)


def preintegration_params(cfg: ImuConfig) -> gtsam.PreintegrationCombinedParams:
    """Combined-IMU parameters: z-up world, ``cfg`` densities (continuous time, squared to covariances)."""
    p = gtsam.PreintegrationCombinedParams.MakeSharedU(cfg.gravity)
    I3 = np.eye(3)
    p.setGyroscopeCovariance(cfg.gyro_noise_density**2 * I3)
    p.setAccelerometerCovariance(cfg.accel_noise_density**2 * I3)
    p.setIntegrationCovariance(1e-8 * I3)
    p.setBiasOmegaCovariance(cfg.gyro_random_walk**2 * I3)
    p.setBiasAccCovariance(cfg.accel_random_walk**2 * I3)
    return p


def preintegrate(
    t: np.ndarray,  # [M] s
    gyro: np.ndarray,  # [M, 3] rad/s, body frame
    accel: np.ndarray,  # [M, 3] m/s^2, body frame
    t0: float,
    t1: float,
    bias: gtsam.imuBias.ConstantBias,
    params: gtsam.PreintegrationCombinedParams,
) -> gtsam.PreintegratedCombinedMeasurements:
    """Preintegrate ``[t0, t1]`` with midpoint samples: each piece between consecutive sample times (the
    first and last cut at ``t0``, ``t1``) uses the samples linearly interpolated at its middle.

    (A zero-order hold lags by half a sample period: on teddy's synthesized 200 Hz IMU it put 1 cm of
    error on 1 s of noise-free integration, and biased a mono+IMU run's scale; midpoints: 0.3 mm.)
    """
    if not (t[0] <= t0 < t1 <= t[-1]):
        raise ImuError(f"IMU samples [{t[0]:.3f}, {t[-1]:.3f}] s do not cover [{t0:.3f}, {t1:.3f}] s")
    inner = t[(t > t0) & (t < t1)]
    knots = np.concatenate([[t0], inner, [t1]])
    mid = 0.5 * (knots[1:] + knots[:-1])
    dts = np.diff(knots)
    g = np.stack([np.interp(mid, t, gyro[:, k]) for k in range(3)], 1)
    a = np.stack([np.interp(mid, t, accel[:, k]) for k in range(3)], 1)
    # gtsam rotates each piece's accel by the rotation at the piece's START; the mean rotation over the
    # piece is half a step further: feed Exp(w dt / 2) a (1 cm -> 0.3 mm on 1 s of noise-free samples)
    a = _rotate(g * (0.5 * dts)[:, None], a)
    pim = gtsam.PreintegratedCombinedMeasurements(params, bias)
    for k in range(len(dts)):
        if dts[k] > 0:
            pim.integrateMeasurement(a[k], g[k], float(dts[k]))
    return pim


def _rotate(w: np.ndarray, x: np.ndarray) -> np.ndarray:  # Exp(w[i]) x[i]; w, x [N, 3]
    th = np.linalg.norm(w, axis=1, keepdims=True)
    k = np.divide(w, th, out=np.zeros_like(w), where=th > 1e-12)
    c, s = np.cos(th), np.sin(th)
    return x * c + np.cross(k, x) * s + k * np.sum(k * x, 1, keepdims=True) * (1 - c)


@dataclass
class ImuInit:
    """Initial gravity-aligned state: ``R_world_body`` of the first state (yaw 0 for a static start),
    biases, and for a visual start the scale and velocities."""

    R_world_body: np.ndarray  # [3, 3]
    gyro_bias: np.ndarray  # [3] rad/s
    accel_bias: np.ndarray  # [3] m/s^2
    gravity_body: np.ndarray  # [3] the measured gravity (static) or estimated one, in the first body frame
    scale: float = 1.0
    velocities: np.ndarray | None = None  # [n, 3] world, m/s
    static: bool = False


def gravity_aligned_rotation(up_body: np.ndarray) -> np.ndarray:
    """``R_world_body`` [3, 3] whose world z is ``up_body`` (unit, body frame); yaw chosen minimal."""
    z = up_body / np.linalg.norm(up_body)
    x0 = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = x0 - z * np.dot(z, x0)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.stack([x, y, z])  # rows: world axes in body coordinates -> R_world_body


def is_static(t: np.ndarray, accel: np.ndarray, max_std: float, block_s: float = 0.1) -> bool:
    """A window of accel samples (``t`` [M] s, ``accel`` [M, 3]) is at rest when the std of its
    ``block_s`` means is below ``max_std`` on every axis (block means: rotor vibration averages out;
    EuRoC V1_01's start has a per-sample std of 0.2-0.6 m/s^2 but 0.1 s means within 0.04-0.06)."""
    if len(t) < 10 or t[-1] - t[0] < 4 * block_s:
        return False
    blocks = np.floor((t - t[0]) / block_s).astype(int)
    n = blocks.max()  # the last, partial block is dropped
    means = np.stack([accel[blocks == b].mean(0) for b in range(n) if np.any(blocks == b)])
    return bool(np.all(means.std(0) < max_std))


def static_init(gyro: np.ndarray, accel: np.ndarray, gravity: float) -> ImuInit:
    """Biases and gravity from IMU samples at rest (``gyro``, ``accel`` [M, 3], body frame)."""
    if len(accel) < 10:
        raise ImuError(f"static initialisation needs >= 10 IMU samples, got {len(accel)}")
    f = accel.mean(0)  # specific force at rest = -gravity in the body frame (i.e. "up" * g)
    norm = float(np.linalg.norm(f))
    up = f / norm
    ba = up * (norm - gravity)  # the bias along gravity; its horizontal part reads as a tilt
    return ImuInit(gravity_aligned_rotation(up), gyro.mean(0), ba, -f, static=True)


def visual_inertial_init(
    times: np.ndarray,  # [n] s, keyframe times (n >= 3)
    T_w_c: np.ndarray,  # [n, 4, 4] rigid camera poses, translation up to scale
    T_c_b: np.ndarray,  # [4, 4] body in the camera frame (metric)
    imu_t: np.ndarray,
    gyro: np.ndarray,
    accel: np.ndarray,
    params: gtsam.PreintegrationCombinedParams,
    gravity: float,
    fixed_scale: float | None = None,
    up_world: np.ndarray | None = None,
) -> ImuInit:
    """Scale, gravity (in the visual world), velocities and gyro bias; see the module docstring.

    ``fixed_scale`` (RGB-D: 1) skips the scale; ``up_world`` (a static start) fixes gravity's direction.
    Returns ``R_world_body`` of the first keyframe in a z-up world (yaw as the visual world's).
    """
    n = len(times)
    if n < 3:
        raise ImuError(f"visual-inertial initialisation needs >= 3 keyframes, got {n}")
    R_wb = T_w_c[:, :3, :3] @ T_c_b[:3, :3]
    d = np.einsum("nij,j->ni", T_w_c[:, :3, :3], T_c_b[:3, 3])  # body origin offset (metric)
    c = T_w_c[:, :3, 3]
    zero = gtsam.imuBias.ConstantBias()
    pims = [preintegrate(imu_t, gyro, accel, times[k], times[k + 1], zero, params) for k in range(n - 1)]
    # gyro bias: Log(dR(0)^T R_i^T R_j) ~ J_bg bg, J_bg = d Log(dR(0)^T dR(bg)) / d bg by differences
    A, b = [], []
    eps = 1e-4
    for k, pim in enumerate(pims):
        dR = pim.deltaRij()
        r = gtsam.Rot3.Logmap(gtsam.Rot3(dR.matrix().T @ R_wb[k].T @ R_wb[k + 1]))
        J = np.zeros((3, 3))
        for a in range(3):
            bg_a = gtsam.imuBias.ConstantBias(np.zeros(3), eps * np.eye(3)[a])
            pa = preintegrate(imu_t, gyro, accel, times[k], times[k + 1], bg_a, params)
            J[:, a] = gtsam.Rot3.Logmap(dR.between(pa.deltaRij())) / eps
        A.append(J)
        b.append(r)
    bg = np.linalg.lstsq(np.vstack(A), np.concatenate(b), rcond=None)[0]
    bias = gtsam.imuBias.ConstantBias(np.zeros(3), bg)
    pims = [preintegrate(imu_t, gyro, accel, times[k], times[k + 1], bias, params) for k in range(n - 1)]

    def solve(g_fixed: np.ndarray | None):
        # unknowns: [s (unless fixed), g (unless fixed), v_0 .. v_{n-1}]
        ns = 0 if fixed_scale is not None else 1
        ng = 0 if g_fixed is not None else 3
        nv = 3 * n
        rows, rhs = [], []
        for k, pim in enumerate(pims):
            dt = times[k + 1] - times[k]
            Ri = R_wb[k]
            dp, dv = pim.deltaPij(), pim.deltaVij()
            # position: s (c_j - c_i) - v_i dt - 1/2 g dt^2 = R_i dp - (d_j - d_i)
            Ap = np.zeros((3, ns + ng + nv))
            bp = Ri @ dp - (d[k + 1] - d[k])
            if ns:
                Ap[:, 0] = c[k + 1] - c[k]
            else:
                bp = bp - fixed_scale * (c[k + 1] - c[k])
            if ng:
                Ap[:, ns : ns + 3] = -0.5 * dt * dt * np.eye(3)
            else:
                bp = bp + 0.5 * dt * dt * g_fixed
            Ap[:, ns + ng + 3 * k : ns + ng + 3 * k + 3] = -dt * np.eye(3)
            # velocity: v_j - v_i - g dt = R_i dv
            Av = np.zeros((3, ns + ng + nv))
            bv = Ri @ dv
            if ng:
                Av[:, ns : ns + 3] = -dt * np.eye(3)
            else:
                bv = bv + dt * g_fixed
            Av[:, ns + ng + 3 * k : ns + ng + 3 * k + 3] = -np.eye(3)
            Av[:, ns + ng + 3 * k + 3 : ns + ng + 3 * k + 6] = np.eye(3)
            rows += [Ap, Av]
            rhs += [bp, bv]
        x = np.linalg.lstsq(np.vstack(rows), np.concatenate(rhs), rcond=None)[0]
        s = float(x[0]) if ns else float(fixed_scale)
        g = x[ns : ns + 3] if ng else g_fixed
        return s, g, x[ns + ng :].reshape(n, 3)

    if up_world is None:
        _, g, _ = solve(None)
        if not np.all(np.isfinite(g)) or np.linalg.norm(g) < 1e-6:
            raise ImuError("visual-inertial initialisation: gravity is not observable (too little motion?)")
        g_dir = g / np.linalg.norm(g)
    else:
        g_dir = -np.asarray(up_world, float) / np.linalg.norm(up_world)
    s, g, v = solve(g_dir * gravity)
    if not np.isfinite(s) or s <= 0:
        raise ImuError(f"visual-inertial initialisation gave scale {s:.3g}; more motion is needed")
    R_z_w = gravity_aligned_rotation(-g_dir)  # z-up world from the visual world
    return ImuInit(
        R_z_w @ R_wb[0], bg, np.zeros(3), R_wb[0].T @ g, scale=s, velocities=v @ R_z_w.T, static=False
    )


class ImuChain:
    """Keyframe IMU states and ``CombinedImuFactor``s on a backend (gtsam factors, buffered)."""

    def __init__(self, backend, cfg: ImuConfig, imu_t: np.ndarray, gyro: np.ndarray, accel: np.ndarray):
        self.backend = backend
        self.cfg = cfg
        self.params = preintegration_params(cfg)
        self.imu_t, self.gyro, self.accel = imu_t, gyro, accel
        self.last: tuple[int, float] | None = None  # (frame, time) of the newest state
        self.states: list[int] = []

    def covers(self, t: float) -> bool:
        return len(self.imu_t) > 1 and self.imu_t[0] <= t <= self.imu_t[-1]

    def start(
        self, f: int, t: float, T_world_body: np.ndarray, velocity: np.ndarray, bias: gtsam.imuBias.ConstantBias,
        velocity_sigma: float = 1.0,
    ) -> None:  # fmt: skip
        """The first state: values, a bias prior (``cfg`` sigmas) and a weak velocity prior."""
        be = self.backend
        be.add_value(keyframe_key(f), gtsam.Pose3(T_world_body))
        be.add_value(V(f), np.asarray(velocity, float))
        be.add_value(B(f), bias)
        sig = np.array([self.cfg.accel_bias_sigma] * 3 + [self.cfg.gyro_bias_sigma] * 3)
        be.add_factor(
            gtsam.PriorFactorConstantBias(B(f), bias, gtsam.noiseModel.Diagonal.Sigmas(sig)),
            f"imu bias prior b{f}",
        )
        be.add_factor(
            gtsam.PriorFactorVector(V(f), np.asarray(velocity, float), gtsam.noiseModel.Isotropic.Sigma(3, velocity_sigma)),
            f"imu velocity prior v{f}",
        )  # fmt: skip
        self.last = (f, t)
        self.states.append(f)

    def add(
        self, f: int, t: float, T_world_body: np.ndarray | None = None, velocity: np.ndarray | None = None
    ) -> int:
        """State ``f`` at time ``t`` with a ``CombinedImuFactor`` from the newest state; returns its handle.

        Initial values: the given pose / velocity, else the IMU prediction from the newest state.
        """
        if self.last is None:
            raise ImuError("ImuChain.add before start")
        f0, t0 = self.last
        be = self.backend
        bias = be.estimate(B(f0)) if be.has_value(B(f0)) else gtsam.imuBias.ConstantBias()
        pim = preintegrate(self.imu_t, self.gyro, self.accel, t0, t, bias, self.params)
        pred = pim.predict(gtsam.NavState(be.estimate(keyframe_key(f0)), be.estimate(V(f0))), bias)
        be.add_value(keyframe_key(f), gtsam.Pose3(T_world_body) if T_world_body is not None else pred.pose())
        be.add_value(V(f), np.asarray(velocity, float) if velocity is not None else pred.velocity())
        be.add_value(B(f), bias)
        h = be.add_factor(
            gtsam.CombinedImuFactor(keyframe_key(f0), V(f0), keyframe_key(f), V(f), B(f0), B(f), pim),
            f"imu x{f0}-x{f}",
        )
        self.last = (f, t)
        self.states.append(f)
        return h


def gravity_gauge_noise(
    R_world_local: np.ndarray, rot_sigma: float, gravity_sigma: float, trans_sigma: float, scale_sigma: float
) -> gtsam.noiseModel.Gaussian:
    """Sim(3) prior noise on the first submap once the world is gravity-aligned: yaw ``rot_sigma``,
    roll/pitch ``gravity_sigma`` (world axes, rotated into the submap's right-chart tangent),
    translation ``trans_sigma``, log-scale ``scale_sigma`` (chart order rot, trans, scale)."""
    Sw = np.diag([gravity_sigma**2, gravity_sigma**2, rot_sigma**2])
    cov = np.zeros((7, 7))
    cov[0:3, 0:3] = R_world_local.T @ Sw @ R_world_local
    cov[3:6, 3:6] = np.eye(3) * trans_sigma**2
    cov[6, 6] = scale_sigma**2
    return gtsam.noiseModel.Gaussian.Covariance(cov)


def add_keyframe_tie(graph, f: int, T_cam_body: np.ndarray, rot_sigma: float, trans_sigma: float) -> int:
    """Tie body pose ``x{f}`` to keyframe ``f``'s pose in a ``SubmapGraph``; returns the handle.

    ``trans_sigma`` is in world units at the submap's current scale ``s``: the factor measures the
    translation in the submap's own units (the visual pose's error does not shrink with the submap, see
    :mod:`gsslam.factors.keyframe_tie`), so it gets ``trans_sigma / s``.
    """
    from gsslam.factors import make_keyframe_tie_factor

    key, L = graph.keyframe_anchor(f)
    U, _, Vt = np.linalg.svd(L[:3, :3])
    L = L.copy()
    L[:3, :3] = U @ Vt
    scale = float(graph.backend.estimate(key).scale())
    sigma = trans_sigma / scale
    factor = make_keyframe_tie_factor(key, keyframe_key(f), L, T_cam_body, rot_sigma, sigma, "sim3")
    return graph.backend.add_factor(factor, f"imu tie x{f}")
