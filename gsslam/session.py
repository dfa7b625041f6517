"""The Python facade: :class:`Slam` feeds frames one by one (kiss-icp's ``KissICP.register_frame``).

>>> slam = gsslam.Slam((fx, fy, cx, cy, width, height), mode="rgbd")
>>> T_world_cam = slam.register_frame(image, timestamp, depth=depth)   # [4, 4] or None
>>> slam.finish(); slam.save("out/")                                     # refined trajectory, map

``gsslam.run(path, ...)`` runs a dataset folder instead (:mod:`gsslam.run`). See docs/python.md.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from gsslam.config import Config, ConfigError, load_config, save_config
from gsslam.errors import GsslamError
from gsslam.slam.pipeline import Pipeline
from gsslam.types import CameraIntrinsics, Frame, Trajectory

log = logging.getLogger(__name__)


class SessionError(GsslamError):
    """The facade was given unusable input (intrinsics, image shape, timestamps out of order)."""


def _intrinsics(value) -> CameraIntrinsics:
    if isinstance(value, CameraIntrinsics):
        return value
    try:
        fx, fy, cx, cy, width, height = value
    except (TypeError, ValueError):
        raise SessionError(
            "intrinsics must be a CameraIntrinsics or (fx, fy, cx, cy, width, height)"
        ) from None
    return CameraIntrinsics(float(fx), float(fy), float(cx), float(cy), int(width), int(height))


def _config(config, mode: str | None, overrides) -> Config:
    if isinstance(config, Config):
        if overrides:
            raise ConfigError("overrides apply to a config file or the defaults, not to a Config object")
        return config if mode is None else _with_mode(config, mode)
    return load_config(config, list(overrides or ()), mode=mode)


def _with_mode(cfg: Config, mode: str) -> Config:
    import dataclasses

    return dataclasses.replace(cfg, mode=mode)


class Slam:
    """Dense mono / RGB-D SLAM, fed frame by frame.

    ``intrinsics``: :class:`~gsslam.types.CameraIntrinsics` or ``(fx, fy, cx, cy, width, height)`` of
    undistorted images. ``config``: a :class:`~gsslam.config.Config`, a YAML path or None (defaults),
    with dotted ``overrides`` (``["mapper.enabled=false"]``) and ``mode`` ("mono" | "rgbd").
    ``plugins``: :class:`gsslam.slam.plugins.Plugin` objects that add factors to the running graph.
    """

    def __init__(self, intrinsics, config=None, *, mode: str | None = None, overrides=(), plugins=()):
        self.config = _config(config, mode, overrides)
        self.intrinsics = _intrinsics(intrinsics)
        self.pipeline = Pipeline(self.config, self.intrinsics)
        for p in plugins:
            self.pipeline.add_plugin(p)
        self._finished = False

    # -- feeding ------------------------------------------------------------------------------
    def register_frame(self, image: np.ndarray, timestamp: float, depth: np.ndarray | None = None):
        """Feed one frame; returns its current pose ``T_world_cam`` [4, 4] (None while it has none).

        ``image``: [H, W, 3] RGB, uint8 or float in [0, 1]; ``depth``: [H, W] metres (0 or NaN invalid),
        needed in RGB-D mode; ``timestamp``: seconds, increasing.
        """
        if self._finished:
            raise SessionError("finish() was called; start a new Slam for more frames")
        image = np.asarray(image)
        if image.ndim != 3 or image.shape[2] != 3:
            raise SessionError(f"image must be [H, W, 3] RGB, got shape {image.shape}")
        image = image.astype(np.float32) / 255.0 if image.dtype == np.uint8 else image.astype(np.float32)
        if depth is not None:
            depth = np.asarray(depth, dtype=np.float32).copy()
            depth[~(depth > 0)] = np.nan
        elif self.config.mode == "rgbd":
            raise SessionError("RGB-D mode needs a depth image with every frame; use mode='mono'")
        ts = self.pipeline.timestamps
        if ts and timestamp <= max(ts.values()):
            raise SessionError(f"timestamp {timestamp} is not after the previous frame's")
        frame = Frame(len(ts), float(timestamp), image, self.intrinsics, depth)
        return self.pipeline.process(frame)

    def finish(self) -> Trajectory:
        """Encode the tail, refine the graph(s) and the map; returns the final trajectory."""
        if not self._finished:
            self.pipeline.finish()
            self._finished = True
        return self.trajectory()

    # -- reading ------------------------------------------------------------------------------
    @property
    def pose(self) -> np.ndarray:
        """The latest camera pose estimate ``T_world_cam`` [4, 4]."""
        return self.pipeline.current_pose_estimate()

    def trajectory(self) -> Trajectory:
        """Every frame's current best pose (after :meth:`finish`: the refined trajectory)."""
        return self._as_trajectory(self.pipeline.frame_poses())

    def online_trajectory(self) -> Trajectory:
        """The poses :meth:`register_frame` returned, as the frames arrived."""
        return self._as_trajectory(self.pipeline.online_poses)

    def keyframe_poses(self) -> dict[int, np.ndarray]:
        return self.pipeline.keyframe_poses()

    @property
    def map(self):
        """The Gaussian map (:class:`gsslam.mapping.mapper.GaussianMapper`), or None when it is off."""
        stage = self.pipeline.map_stage
        return None if stage is None else stage.mapper

    def add_plugin(self, plugin) -> None:
        self.pipeline.add_plugin(plugin)

    def save(self, out: str | Path) -> Path:
        """``trajectory.tum``, ``keyframes.tum``, ``config.yaml`` and, with a map, ``map.ply`` in ``out``."""
        from gsslam.io.trajectory import write_tum

        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        write_tum(self.trajectory(), out / "trajectory.tum")
        write_tum(self._as_trajectory(self.keyframe_poses()), out / "keyframes.tum")
        save_config(self.config, out / "config.yaml")
        if self.map is not None:
            self.map.save_ply(out / "map.ply")
        return out

    def _as_trajectory(self, poses: dict[int, np.ndarray]) -> Trajectory:
        ts = self.pipeline.timestamps
        idx = sorted(i for i in poses if i in ts)
        if not idx:
            return Trajectory(np.zeros(0), np.zeros((0, 4, 4)))
        return Trajectory(np.array([ts[i] for i in idx]), np.stack([poses[i] for i in idx]))
