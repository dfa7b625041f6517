"""Which camera the written trajectory is: the colour camera, or the one the dataset's ground truth poses.

The pipeline tracks the colour camera: its images are what the flow, the map and the keyframe images see.
A dataset's ground truth may belong to another camera of the same rig. Microsoft 7-Scenes' ``pose.txt``
are the *depth* camera's poses (its ground truth is KinectFusion run on the depth images; the colour camera
sits ~2.5 cm beside it, and 7-Scenes does not register the two). A colour-camera trajectory compared with
depth-camera poses carries that lever arm as error wherever the camera turns: on a 1000-frame room walked
and revisited from new directions it is ~2 cm RMS after SE(3) alignment, more than the tracking's own error
(docs/results.md, "The trajectory's camera, session 16").

``run.trajectory_camera``:

- ``"ground_truth"`` (default): the camera the dataset says its ground truth belongs to
  (``dataset.ground_truth_camera``: ``"depth"`` for 7-Scenes and for the proxies that simulate it,
  ``"colour"`` otherwise);
- ``"colour"``: always the colour camera;
- ``"depth"``: the depth camera.

The depth camera's pose is ``T_world_colour @ T_colour_depth``, ``T_colour_depth`` from the run's applied
depth-to-colour registration (the baseline along x, and the depth camera's turn where one is given; see
:mod:`gsslam.frontend.depth_registration`). Without one (registered depth, or a mono run, which has no
metric baseline) the two cameras are one and ``trajectory.tum`` is the colour camera's. When the written
camera is not the colour camera, the colour camera's poses are written beside it (``trajectory_colour.tum``,
``keyframes_colour.tum``): exports, renders and the viewer pair them with the colour images
(:func:`image_poses_file`).

With a delay between each frame's colour and depth images (``encoder.depth_delay_s``, session 17), the depth
camera is written at its own image's time, as 7-Scenes' KinectFusion poses are: ``T_world_colour(t) D(t)
T_colour_depth``, ``D`` the colour camera's motion over the delay from the velocity between the frame's two
neighbours (:func:`gsslam.frontend.depth_retiming.delay_motions`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gsslam.frontend.depth_retiming import delay_motions

log = logging.getLogger(__name__)

CAMERAS = ("ground_truth", "colour", "depth")
COLOUR_SUFFIX = "_colour"  # trajectory_colour.tum, keyframes_colour.tum


@dataclass(frozen=True)
class TrajectoryCamera:
    """The written trajectory's camera and its pose in the colour camera frame (identity: colour)."""

    name: str = "colour"
    T_colour_cam: np.ndarray = field(default_factory=lambda: np.eye(4))
    delay_s: float = 0.0  # the camera's image taken this long after the colour image (a depth camera's)

    @property
    def is_colour(self) -> bool:
        return bool(np.array_equal(self.T_colour_cam, np.eye(4)))

    def apply(
        self,
        poses: dict[int, np.ndarray],  # frame -> T_world_colour [4, 4]
        timestamps: dict[int, float] | None = None,  # frame -> its colour image's time
        velocity_from: dict[int, np.ndarray] | None = None,  # whose neighbours give D (default: poses)
    ) -> dict[int, np.ndarray]:
        """``T_world_colour`` per frame -> ``T_world_cam`` of this camera (at its own image's time where
        ``delay_s`` and the frames' ``timestamps`` are given; keyframes take D from every frame's poses)."""
        if self.is_colour:
            return poses
        if self.delay_s == 0.0 or timestamps is None:
            return {i: T @ self.T_colour_cam for i, T in poses.items()}
        D = delay_motions(poses if velocity_from is None else velocity_from, timestamps, self.delay_s)
        return {i: T @ D.get(i, np.eye(4)) @ self.T_colour_cam for i, T in poses.items()}

    def record(self) -> dict:
        """For ``metrics.json``."""
        T = self.T_colour_cam.tolist()
        rec = {"camera": self.name, "T_colour_camera": T, "colour_files": not self.is_colour}
        return {**rec, "delay_s": self.delay_s} if self.delay_s else rec


COLOUR = TrajectoryCamera()


def ground_truth_camera(ds) -> str:
    """The camera the dataset's ground truth poses (``"colour"`` unless the dataset says otherwise)."""
    cam = getattr(ds, "ground_truth_camera", "colour")
    return cam if cam in ("colour", "depth") else "colour"


def trajectory_camera(
    choice: str, ds, T_colour_depth: np.ndarray | None, delay_s: float = 0.0
) -> TrajectoryCamera:
    """The camera to write (``run.trajectory_camera``); ``T_colour_depth``: the applied registration's depth
    camera in the colour frame (``DepthRegistration.T_colour_depth``), ``None`` without a registration
    (registered depth, mono); ``delay_s``: the depth images' delay after the colour images (module doc)."""
    if choice not in CAMERAS:
        raise ValueError(f"run.trajectory_camera must be one of {CAMERAS}, got {choice!r}")
    name = ground_truth_camera(ds) if choice == "ground_truth" else choice
    if name == "colour":
        return COLOUR
    if T_colour_depth is None:
        log.warning(
            "the ground truth is the depth camera's, but this run has no depth-to-colour registration "
            "(mono, or depth taken as registered): trajectory.tum is the colour camera's, and its ATE "
            "includes the lever arm between the two cameras (~2.5 cm on a Kinect v1)"
        )
        return TrajectoryCamera("colour")
    log.info(
        "trajectory.tum is the depth camera's (%.1f mm beside the colour camera along x), as the "
        "dataset's ground truth; the colour camera's is in trajectory_colour.tum", 1000 * T_colour_depth[0, 3],
    )  # fmt: skip
    return TrajectoryCamera("depth", np.array(T_colour_depth, dtype=np.float64), float(delay_s))


def image_poses_file(run_dir: Path, stem: str) -> Path:
    """The file with the colour camera's poses (the images' camera): ``stem_colour.tum`` when the run wrote
    one (its trajectory is another camera's), else ``stem.tum``."""
    colour = Path(run_dir) / f"{stem}{COLOUR_SUFFIX}.tum"
    return colour if colour.is_file() else Path(run_dir) / f"{stem}.tum"
