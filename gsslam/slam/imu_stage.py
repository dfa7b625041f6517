"""IMU in the run: preintegrated ``CombinedImuFactor``s between consecutive keyframes (``--imu``).

A built-in :class:`gsslam.slam.plugins.Plugin` (the runner adds it when ``imu.enabled``):

- **Formulation.** The visual graph keeps its Sim(3) submap variables; every keyframe ``f`` with IMU
  data gets a body pose ``x{f}`` (Pose3 ``T_world_imu``), a velocity ``v{f}`` and a bias ``b{f}``,
  tied to its submap by :func:`gsslam.graph.imu.add_keyframe_tie` (``x{f} ~ rigid(S_i L_j) T_cam_imu``;
  the extrinsic from the dataset: EuRoC ``T_BS``) and chained by gtsam's ``CombinedImuFactor``.
- **Initialisation** (once per chain, after the chain's first submap that holds
  ``imu.min_init_keyframes`` keyframes with IMU between them): gyro bias, gravity direction,
  velocities and (mono) the metric scale from the visual keyframe poses and the preintegrated IMU
  (:func:`gsslam.graph.imu.visual_inertial_init`); when the IMU rests for ``imu.static_window_s``
  before the first keyframe, gravity and gyro bias come from those samples instead
  (:func:`gsslam.graph.imu.static_init`). The graph's world is then moved onto a z-up, metric world
  (a Sim(3) ``G`` on the first submap: a tight prior at ``G S_0``, one update), and the gauge prior
  becomes: yaw and position fixed, roll/pitch ``imu.gravity_sigma``, scale free in mono.
- Later submaps: their keyframes get states, ties and IMU factors; the pipeline's update sends them.

Every chain gets its own IMU states (a chain started after tracking loss is initialised like the
first, on its own first submaps; no IMU factor crosses the gap). The first chain's world move moves the
output world (z-up, metric); a later chain's move is compensated in its ``T_world_chain``
(:meth:`gsslam.slam.plugins.GraphEvent.keep_output_world`), so its poses in the output world do not
jump, and its graph is gravity-aligned and (mono) metric inside.
"""

from __future__ import annotations

import logging

import gtsam
import numpy as np

from gsslam.config import Config
from gsslam.errors import GsslamError
from gsslam.graph.imu import (
    ImuChain,
    ImuError,
    add_keyframe_tie,
    gravity_gauge_noise,
    is_static,
    preintegration_params,
    static_init,
    visual_inertial_init,
)
from gsslam.graph.keys import submap_key
from gsslam.slam.plugins import GraphEvent, Plugin
from gsslam.types import ImuSamples

log = logging.getLogger(__name__)


class ImuStage(Plugin):
    """Adds IMU states and factors to every chain's graph; ``report`` holds the first chain's
    initialisation (later chains': ``report["later_chains"]``)."""

    def __init__(self, cfg: Config, samples: ImuSamples, T_body_cam: np.ndarray) -> None:
        if len(samples) < 2:
            raise ImuError("the dataset gave fewer than 2 IMU samples")
        self.cfg = cfg
        self.icfg = cfg.imu
        self.monocular = cfg.mode == "mono"
        self.samples = samples
        T_imu_cam = np.linalg.inv(samples.T_body_imu) @ np.asarray(T_body_cam, float)
        self.T_cam_imu = np.linalg.inv(T_imu_cam)
        self.times: dict[int, float] = {}
        self.chains: dict[int, ImuChain] = {}  # pipeline chain id -> its IMU states
        self.report: dict = {"initialized": False, "static_prefix": self._static_prefix()}

    @property
    def chain(self) -> ImuChain | None:
        """The first chain's IMU states (the one ``report`` and ``estimates`` describe)."""
        return self.chains.get(0)

    def _static_prefix(self) -> dict | None:
        """Gravity and biases from the first ``imu.static_window_s`` of IMU when it rests there (logged
        and reported even when no keyframe follows, e.g. a camera that never moves)."""
        s, c = self.samples, self.icfg
        w = s.timestamps <= s.timestamps[0] + c.static_window_s
        if not is_static(s.timestamps[w], s.accel[w], c.static_max_accel_std):
            return None
        init = static_init(s.gyro[w], s.accel[w], c.gravity)
        out = {
            "seconds": float(s.timestamps[w][-1] - s.timestamps[0]),
            "gravity_body": [float(x) for x in init.gravity_body],
            "gravity_norm": float(np.linalg.norm(init.gravity_body)),
            "gyro_bias": [float(x) for x in init.gyro_bias],
            "accel_bias_along_gravity": float(np.linalg.norm(init.gravity_body) - c.gravity),
        }
        log.info("IMU at rest over the first %.2f s: %s", out["seconds"], out)
        return out

    # ---- hooks -------------------------------------------------------------------------------
    def on_keyframe(self, event: GraphEvent) -> None:
        if event.timestamp is not None:
            self.times[event.frame_index] = float(event.timestamp)

    def on_submap(self, event: GraphEvent) -> None:
        cid = event.chain
        if cid in self.chains:
            self._extend(self.chains[cid], event.graph)
            return
        out = self._initialize(event.graph)
        if out is None:
            return
        chain, G, report = out
        self.chains[cid] = chain
        if cid == 0:
            self.report = {**self.report, **report}
        else:  # the output world stays the first chain's
            event.keep_output_world(G)
            self.report.setdefault("later_chains", {})[str(cid)] = report

    # ---- states ------------------------------------------------------------------------------
    def _covered(self, graph) -> list[int]:
        """Keyframes of the graph (in time order) with a time inside the IMU's span."""
        t = self.samples.timestamps
        kfs = sorted(f for f in graph.keyframe_poses() if f in self.times)
        return [f for f in kfs if t[0] <= self.times[f] <= t[-1]]

    def _initialize(self, graph) -> tuple[ImuChain, np.ndarray, dict] | None:
        """Initialise a chain's graph: (its IMU states, the Sim(3) ``G`` that moved its world, report)."""
        kfs = self._covered(graph)
        if len(kfs) < self.icfg.min_init_keyframes:
            log.info("IMU: %d keyframes with IMU so far; initialisation waits", len(kfs))
            return None
        s = self.samples
        params = preintegration_params(self.icfg)
        poses = graph.keyframe_poses()
        times = np.array([self.times[f] for f in kfs])
        T_w_c = np.stack([poses[f] for f in kfs])
        T_c_b = self.T_cam_imu
        win = (s.timestamps >= times[0] - self.icfg.static_window_s) & (s.timestamps <= times[0])
        up_world, static = None, None
        if is_static(s.timestamps[win], s.accel[win], self.icfg.static_max_accel_std):
            static = static_init(s.gyro[win], s.accel[win], self.icfg.gravity)
            R_wb0 = T_w_c[0, :3, :3] @ T_c_b[:3, :3]
            up_world = R_wb0 @ (-static.gravity_body / np.linalg.norm(static.gravity_body))
        try:
            init = visual_inertial_init(
                times, T_w_c, T_c_b, s.timestamps, s.gyro, s.accel, params, self.icfg.gravity,
                fixed_scale=None if self.monocular else 1.0, up_world=up_world,
            )  # fmt: skip
        except ImuError as e:
            log.warning("IMU initialisation postponed: %s", e)
            return None
        gyro_bias = static.gyro_bias if static is not None else init.gyro_bias
        accel_bias = static.accel_bias if static is not None else init.accel_bias
        R_z_w = init.R_world_body @ (T_w_c[0, :3, :3] @ T_c_b[:3, :3]).T  # visual world -> z-up world
        G = self._move_world(graph, R_z_w, init.scale)
        chain = ImuChain(graph.backend, self.icfg, s.timestamps, s.gyro, s.accel)
        bias = gtsam.imuBias.ConstantBias(accel_bias, gyro_bias)
        poses = graph.keyframe_poses()
        for k, f in enumerate(kfs):
            X = poses[f] @ T_c_b
            if k == 0:
                chain.start(f, self.times[f], X, init.velocities[0], bias)
            else:
                chain.add(f, self.times[f], X, init.velocities[k])
            add_keyframe_tie(graph, f, T_c_b, self.icfg.tie_rot_sigma, self.icfg.tie_trans_sigma)
        report = {
            "initialized": True,
            "static_start": static is not None,
            "keyframes": len(kfs),
            "scale": float(init.scale),
            "gyro_bias": [float(x) for x in gyro_bias],
            "accel_bias": [float(x) for x in accel_bias],
            "gravity_body": [
                float(x) for x in (static.gravity_body if static is not None else init.gravity_body)
            ],
        }
        log.info("IMU initialised: %s", report)
        return chain, G, report

    def _move_world(self, graph, R_z_w: np.ndarray, scale: float) -> np.ndarray:
        """Map the graph onto the z-up metric world ``G = Sim3(R_z_w, 0, scale)`` through s0's gauge;
        returns ``G`` [4, 4]."""
        gc = self.cfg.graph
        be = graph.backend
        key = submap_key(0)
        G = gtsam.Similarity3(gtsam.Rot3(R_z_w), np.zeros(3), float(scale))
        target = G.compose(be.estimate(key))
        if graph.gauge_handle is not None:
            graph.remove_factor(graph.gauge_handle)
        tight = gtsam.noiseModel.Isotropic.Sigma(7, 1e-6)
        h = be.add_factor(gtsam.PriorFactorSimilarity3(key, target, tight), "imu world alignment s0")
        be.update(extra_iterations=5)
        graph.remove_factor(h)
        R_s0 = target.rotation().matrix()
        scale_sigma = 10.0 if self.monocular else gc.prior_scale_sigma  # mono: the IMU gives the scale
        noise = gravity_gauge_noise(
            R_s0, gc.prior_rot_sigma, self.icfg.gravity_sigma, gc.prior_trans_sigma, scale_sigma
        )
        graph.gauge_handle = be.add_factor(
            gtsam.PriorFactorSimilarity3(key, target, noise), "gauge prior s0 (gravity)"
        )
        out = np.eye(4)
        out[:3, :3] = float(scale) * R_z_w
        return out

    def _extend(self, chain: ImuChain, graph) -> None:
        last = chain.last[0]
        poses = graph.keyframe_poses()
        for f in self._covered(graph):
            if f <= last:
                continue
            try:
                chain.add(f, self.times[f], poses[f] @ self.T_cam_imu)
            except GsslamError as e:
                log.warning("IMU: keyframe %d: %s", f, e)
                continue
            add_keyframe_tie(graph, f, self.T_cam_imu, self.icfg.tie_rot_sigma, self.icfg.tie_trans_sigma)

    def estimates(self, graph) -> dict:
        """Final biases and velocities of the IMU states (for metrics.json)."""
        if self.chain is None:
            return {}
        be = graph.backend
        from gsslam.graph.imu import B

        last = self.chain.states[-1]
        b = be.estimate(B(last))
        return {
            "states": len(self.chain.states),
            "final_accel_bias": [float(x) for x in b.accelerometer()],
            "final_gyro_bias": [float(x) for x in b.gyroscope()],
        }
