"""The ``synthetic`` dataset: lazily ray-cast RGB-D frames with exact depth and ground-truth poses.

``open_dataset("synthetic", path)``: ``path`` is a YAML file (or a folder holding
``synthetic.yaml``) whose keys are the constructor's keyword arguments, e.g.::

    n_frames: 60
    width: 320
    height: 240
    scene: room
    trajectory: loop
    seed: 3

``focal_scale`` (default 1): the intrinsics handed out with the frames are the true ones with both
focal lengths times this (a mis-calibrated camera, e.g. 1.114 as the 7-Scenes loader hands out the
depth camera's 585 px for a 525 px colour camera); the frames are rendered with the true ones, and
the depth stays the true depth (a mono run reads no depth).

What a hand-held Kinect v1 adds (each ``None`` by default: exact frames; docs/evaluation.md, "A long
synthetic room"):

- ``sensor``: ``"kinect_v1"`` or a dict of :class:`~gsslam.datasets.depth_sensor.KinectV1`'s fields:
  depth noise ~ z^2, disparity quantization, holes (range, grazing angles, depth edges), drawn from
  ``seed`` and the frame index, in the depth camera's grid.
- ``misregister``: a dict as the ``playback`` dataset's (:mod:`gsslam.datasets.misregistered`): the
  exact depth is first re-rendered into a depth camera ``baseline_m`` beside the colour camera (turned
  by ``rotation_deg``, offset by ``offset_m``) with focal lengths ``focal_scale`` times longer, handed
  out at the colour pixels; ``report: depth`` hands out the depth camera's intrinsics for colour too
  (as 7-Scenes does; then ``focal_scale`` must be 1).
- ``degrade``: a dict as the ``playback`` dataset's (:mod:`gsslam.datasets.degraded`): motion blur
  along the exact motion to the neighbouring frames (from the exact depth) and exposure swings.
- ``depth_delay_s`` (default 0: colour and depth at one pose): the depth image is taken this many
  seconds after the colour image (negative: before), as a Kinect v1's unsynchronised streams are
  (up to half a frame, ~16 ms, either way): it is rendered at the pose interpolated at ``t + delay``
  (:func:`~gsslam.geometry.interpolate_pose` between the path's neighbouring poses, extrapolated at the
  ends). The ground truth poses its camera at that camera's time: the colour camera at ``t``, or with
  ``misregister: {ground_truth: depth}`` the depth camera at ``t + delay`` (7-Scenes' KinectFusion poses
  are the depth images'). ``timestamps()`` stay the colour images'.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import yaml

from gsslam.datasets.degraded import Degradation, apply_exposure, exposure_ends, motion_blur
from gsslam.datasets.depth_sensor import KinectV1, kinect_v1_depth
from gsslam.datasets.misregistered import Misregistration, misregister_depth
from gsslam.datasets.synthetic.presets import PRESETS
from gsslam.datasets.synthetic.scene import SceneError
from gsslam.datasets.synthetic.trajectories import orbit, room_walk, sway_line
from gsslam.geometry import interpolate_pose
from gsslam.types import CameraIntrinsics, Frame, Trajectory

# name -> (n_frames, arc_deg, motion_scale, seed) -> T_world_cam [N, 4, 4]; add a path here to offer it
TRAJECTORIES = {
    "orbit": lambda n, arc_deg, s, seed: orbit(n, arc_deg, s),
    "line": lambda n, arc_deg, s, seed: sway_line(n, s),
    "loop": lambda n, arc_deg, s, seed: orbit(n, 360.0, s),
    "room_walk": lambda n, arc_deg, s, seed: room_walk(n, s, seed),
}
_PARAMS = (
    "n_frames",
    "width",
    "height",
    "scene",
    "trajectory",
    "seed",
    "motion_scale",
    "arc_deg",
    "fps",
    "focal_scale",
    "sensor",
    "misregister",
    "degrade",
    "depth_delay_s",
)


class SyntheticDatasetError(SceneError):
    """Bad parameters for the synthetic scene."""


class SyntheticDataset:
    """Ray-cast RGB-D frames of a preset scene (default: the textured ``room``) along a named path."""

    name = "synthetic"
    has_depth = True

    def __init__(
        self,
        path: str | Path | None = None,
        n_frames: int = 60,
        width: int = 320,
        height: int = 240,
        trajectory: str = "orbit",
        seed: int = 0,
        motion_scale: float = 1.0,
        arc_deg: float = 90.0,
        fps: float = 30.0,
        scene: str = "room",
        focal_scale: float = 1.0,
        sensor: str | dict[str, Any] | None = None,
        misregister: dict[str, Any] | None = None,
        degrade: dict[str, Any] | None = None,
        depth_delay_s: float = 0.0,
    ) -> None:
        params: dict[str, Any] = dict(
            n_frames=n_frames,
            width=width,
            height=height,
            scene=scene,
            trajectory=trajectory,
            seed=seed,
            motion_scale=motion_scale,
            arc_deg=arc_deg,
            fps=fps,
            focal_scale=focal_scale,
            sensor=sensor,
            misregister=misregister,
            degrade=degrade,
            depth_delay_s=depth_delay_s,
        )
        if path is not None:
            params.update(self._read_params(Path(path)))
        self.params = params
        self.n_frames = int(params["n_frames"])
        self.trajectory = str(params["trajectory"])
        self.motion_scale = float(params["motion_scale"])
        self.fps = float(params["fps"])
        w, h = int(params["width"]), int(params["height"])
        if self.n_frames < 1:
            raise SyntheticDatasetError(f"n_frames must be >= 1, got {self.n_frames}")
        if w < 16 or h < 16:
            raise SyntheticDatasetError(f"image size must be at least 16x16, got {w}x{h}")
        if self.trajectory not in TRAJECTORIES:
            raise SyntheticDatasetError(
                f"trajectory must be one of {', '.join(TRAJECTORIES)}, got {self.trajectory!r}"
            )
        if params["scene"] not in PRESETS:
            raise SyntheticDatasetError(f"scene must be one of {', '.join(PRESETS)}, got {params['scene']!r}")
        if not 0.0 < self.motion_scale <= 2.0:
            raise SyntheticDatasetError(f"motion_scale must be in (0, 2], got {self.motion_scale}")
        focal_scale = float(params["focal_scale"])
        if not (np.isfinite(focal_scale) and 0.5 <= focal_scale <= 2.0):
            raise SyntheticDatasetError(f"focal_scale must be in [0.5, 2], got {focal_scale}")
        f = 0.8 * w
        self.true_intrinsics = CameraIntrinsics(f, f, (w - 1) / 2.0, (h - 1) / 2.0, w, h)  # renders
        fr = f * focal_scale
        self.intrinsics = CameraIntrinsics(fr, fr, (w - 1) / 2.0, (h - 1) / 2.0, w, h)  # handed out
        self.seed = int(params["seed"])
        self.sensor = KinectV1.from_spec(params["sensor"])
        self.misregistration = Misregistration.from_dict(params["misregister"])
        self.degradation = Degradation.from_dict(params["degrade"])
        if self.misregistration is not None:
            if focal_scale != 1.0 and self.misregistration.report == "depth":
                raise SyntheticDatasetError("give focal_scale or misregister.report=depth, not both")
            if self.misregistration.report == "depth":
                self.intrinsics = self.misregistration.depth_intrinsics(self.true_intrinsics)
        # handed out with another camera's focal (the 7-Scenes hand-out): nominal, as the 7-Scenes loader says
        self.intrinsics_nominal = self.intrinsics != self.true_intrinsics
        self.depth_delay_s = float(params["depth_delay_s"])
        if not (np.isfinite(self.depth_delay_s) and abs(self.depth_delay_s) * self.fps <= 1.0):
            raise SyntheticDatasetError(
                f"depth_delay_s must be within one frame (|delay| <= {1.0 / self.fps:.4f} s), "
                f"got {self.depth_delay_s}"
            )
        self.scene = PRESETS[params["scene"]](seed=self.seed)
        self._poses = TRAJECTORIES[self.trajectory](
            self.n_frames, float(params["arc_deg"]), self.motion_scale, self.seed
        )
        # the colour camera's poses when each depth image is taken (the colour poses themselves: no delay)
        self._depth_time_poses = delayed_poses(self._poses, self.depth_delay_s * self.fps)

    @staticmethod
    def _read_params(path: Path) -> dict:
        p = path / "synthetic.yaml" if path.is_dir() else path
        if not p.is_file():
            raise SyntheticDatasetError(
                f"no synthetic scene description at {p} (a YAML of {', '.join(_PARAMS)})"
            )
        try:
            data = yaml.safe_load(p.read_text()) or {}
        except yaml.YAMLError as e:
            raise SyntheticDatasetError(f"{p} is not valid YAML: {e}") from None
        if not isinstance(data, dict):
            raise SyntheticDatasetError(f"{p} must hold a mapping of parameters")
        unknown = set(data) - set(_PARAMS)
        if unknown:
            raise SyntheticDatasetError(f"{p}: unknown keys {sorted(unknown)}; known: {', '.join(_PARAMS)}")
        return data

    def __len__(self) -> int:
        return self.n_frames

    def timestamps(self) -> list[float]:
        return [i / self.fps for i in range(self.n_frames)]

    @property
    def ground_truth_camera(self) -> str:  # the camera ground_truth() poses (misregister.ground_truth)
        return "colour" if self.misregistration is None else self.misregistration.ground_truth

    def _truth(self, index: int | slice) -> np.ndarray:  # the ground truth's poses, each at its camera's time
        mr = self.misregistration
        if mr is None or mr.ground_truth == "colour":
            return self._poses[index].copy()
        return mr.ground_truth_poses(self._depth_time_poses[index])

    def ground_truth(self) -> Trajectory:
        return Trajectory(np.asarray(self.timestamps()), self._truth(slice(None)))

    def __getitem__(self, index: int) -> Frame:
        if not -self.n_frames <= index < self.n_frames:
            raise IndexError(f"frame {index} out of range for {self.n_frames} frames")
        index = index % self.n_frames
        image, depth = self.render(self._poses[index])
        image, depth = self._as_captured(index, image, depth)
        return Frame(
            index=index,
            timestamp=index / self.fps,
            image=image,
            intrinsics=self.intrinsics,
            depth=depth,
            T_world_cam_gt=self._truth(index),
        )

    def _as_captured(
        self, index: int, image: np.ndarray, depth: np.ndarray  # [H, W, 3], [H, W] exact
    ) -> tuple[np.ndarray, np.ndarray]:
        """The frame as the hand-held sensor hands it out (module docstring); unchanged by default."""
        deg, mr = self.degradation, self.misregistration
        if deg is not None:
            if deg.blurs:
                prev = self._poses[index - 1] if index > 0 else None
                nxt = self._poses[index + 1] if index + 1 < self.n_frames else None
                ends = exposure_ends(deg, prev, self._poses[index], nxt)
                image = motion_blur(image, depth, self.true_intrinsics, ends, deg.blur_samples)
            image = apply_exposure(image, deg.gain(index))
        depth_intr = self.true_intrinsics
        T_world_at_depth = self._depth_time_poses[index]  # the colour camera when the depth is taken
        if self.depth_delay_s != 0.0:
            depth = self.render(T_world_at_depth)[1]
        if mr is not None:
            depth_intr = mr.depth_intrinsics(self.true_intrinsics)
            if mr.raycast:  # the depth camera itself, at its pose in the colour camera (x = baseline_m ...)
                T_cam_depth = mr.T_colour_depth()
                depth = self.scene.cast(T_world_at_depth @ T_cam_depth, depth_intr)[1].astype(np.float32)
            else:
                depth = misregister_depth(
                    depth, self.true_intrinsics, mr.baseline_m, mr.focal_scale, mr.rotation_deg, mr.offset_m
                )
        if self.sensor is not None:
            rng = np.random.default_rng([self.seed, index, 1])
            depth = kinect_v1_depth(depth, depth_intr, self.sensor, rng)
        return image, depth

    def render(self, T_world_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ray-cast the scene from ``T_world_cam`` [4, 4] -> (image [H, W, 3], depth [H, W] float32)."""
        image, depth = self.scene.cast(T_world_cam, self.true_intrinsics)
        return image, depth.astype(np.float32)


def delayed_poses(poses: np.ndarray, shift_frames: float) -> np.ndarray:  # [N, 4, 4], frames -> [N, 4, 4]
    """The poses ``shift_frames`` frames later along the path (``poses`` itself when 0): each between the
    two poses around ``k + shift`` (:func:`~gsslam.geometry.interpolate_pose`), the first / last pair's
    motion extrapolated past the ends."""
    n = len(poses)
    if shift_frames == 0.0 or n < 2:
        return poses
    out = np.empty_like(poses)
    for k in range(n):
        f = k + shift_frames
        i = int(min(max(np.floor(f), 0), n - 2))
        out[k] = interpolate_pose(poses[i], poses[i + 1], f - i)
    return out
