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
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import yaml

from gsslam.datasets.synthetic.presets import PRESETS
from gsslam.datasets.synthetic.scene import SceneError
from gsslam.datasets.synthetic.trajectories import orbit, sway_line
from gsslam.types import CameraIntrinsics, Frame, Trajectory

# name -> (n_frames, arc_deg, motion_scale) -> T_world_cam [N, 4, 4]; add a path here to offer it
TRAJECTORIES = {
    "orbit": lambda n, arc_deg, s: orbit(n, arc_deg, s),
    "line": lambda n, arc_deg, s: sway_line(n, s),
    "loop": lambda n, arc_deg, s: orbit(n, 360.0, s),
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
        self.scene = PRESETS[params["scene"]](seed=int(params["seed"]))
        self._poses = TRAJECTORIES[self.trajectory](
            self.n_frames, float(params["arc_deg"]), self.motion_scale
        )

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

    def ground_truth(self) -> Trajectory:
        return Trajectory(np.asarray(self.timestamps()), self._poses.copy())

    def __getitem__(self, index: int) -> Frame:
        if not -self.n_frames <= index < self.n_frames:
            raise IndexError(f"frame {index} out of range for {self.n_frames} frames")
        index = index % self.n_frames
        image, depth = self.render(self._poses[index])
        return Frame(
            index=index,
            timestamp=index / self.fps,
            image=image,
            intrinsics=self.intrinsics,
            depth=depth,
            T_world_cam_gt=self._poses[index].copy(),
        )

    def render(self, T_world_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ray-cast the scene from ``T_world_cam`` [4, 4] -> (image [H, W, 3], depth [H, W] float32)."""
        image, depth = self.scene.cast(T_world_cam, self.true_intrinsics)
        return image, depth.astype(np.float32)
