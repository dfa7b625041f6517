"""Microsoft 7-Scenes sequences (``seq-XX/frame-XXXXXX.color.png | .depth.png | .pose.txt``).

Shotton et al., "Scene Coordinate Regression Forests for Camera Relocalization in RGB-D Images",
CVPR 2013.

- ``path``: a ``seq-XX`` folder, or the scene folder (e.g. ``chess/``) with ``sequence="seq-01"``
  (or ``sequence=1``).
- Frames: every ``frame-XXXXXX.color.png`` sorted by number; timestamps ``index / fps``
  (``fps=30``, 7-Scenes has no timestamps).
- Depth: ``frame-XXXXXX.depth.png`` in millimetres; 0 and 65535 are invalid (NaN). Note that the
  Kinect depth of 7-Scenes is *not* registered to the colour camera (the original release says so);
  this loader hands it out as is, at the colour resolution. ``with_depth=False`` skips it.
- Intrinsics: fx=fy=585, cx=320, cy=240, 640x480 unless ``intrinsics=`` is given; no distortion.
  These are the depth camera's, so the dataset says its intrinsics are nominal
  (``intrinsics_nominal``): a mono run then calibrates the focal from the images
  (``encoder.mono_focal_auto_nominal``).
- Ground truth: ``frame-XXXXXX.pose.txt``, a 4x4 camera-to-world matrix ``T_world_cam`` of the *depth*
  camera (the poses are KinectFusion's on the depth images; ``ground_truth_camera = "depth"``, so an RGB-D
  run writes the depth camera's trajectory from its registration estimate:
  :mod:`gsslam.run.trajectory_camera`). Every pose
  file is read when the dataset is opened, so a malformed one is refused before a run starts; a
  missing file or a non-finite matrix (the convention for an untracked frame) gives ``None`` for
  that frame.
- Image sizes (and 16-bit depth) are checked from the file headers when the dataset is opened.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path

import numpy as np

from gsslam.datasets.base import DatasetError
from gsslam.datasets.common import normalize_index
from gsslam.datasets.image_io import check_image_files, read_color, read_depth
from gsslam.types import CameraIntrinsics, Frame, Trajectory

log = logging.getLogger(__name__)

SEVEN_SCENES_INTRINSICS = CameraIntrinsics(585.0, 585.0, 320.0, 240.0, 640, 480)
DEPTH_SCALE = 1000.0  # millimetres
INVALID_DEPTH = (0, 65535)
_FRAME_RE = re.compile(r"^frame-(\d+)\.color\.png$")


class SevenScenesError(DatasetError):
    """A 7-Scenes folder or one of its files is missing or malformed."""


def read_pose_txt(path: Path) -> np.ndarray | None:  # -> [4, 4] or None when absent / not finite
    if not path.is_file():
        return None
    fix = "fix the file, or delete it (a frame without pose.txt has no ground truth)"
    try:
        T = np.loadtxt(path, dtype=np.float64, ndmin=2)
    except (ValueError, UnicodeDecodeError):
        raise SevenScenesError(f"{path}: expected a 4x4 matrix of numbers; {fix}") from None
    if T.shape != (4, 4):
        raise SevenScenesError(f"{path}: expected a 4x4 matrix, got shape {T.shape}; {fix}")
    if not np.all(np.isfinite(T)):
        return None
    return T


class SevenScenesDataset:
    """One 7-Scenes sequence; see the module docstring for the kwargs."""

    ground_truth_camera = "depth"  # pose.txt: KinectFusion's depth-camera poses

    def __init__(
        self,
        path: str | Path,
        *,
        sequence: str | int | None = None,
        fps: float = 30.0,
        with_depth: bool = True,
        intrinsics: CameraIntrinsics | None = None,
    ) -> None:
        seq_dir = Path(path)
        if sequence is not None:
            name = f"seq-{int(sequence):02d}" if str(sequence).isdigit() else str(sequence)
            seq_dir = seq_dir / name
        if not seq_dir.is_dir():
            raise SevenScenesError(f"7-Scenes sequence folder does not exist: {seq_dir}")
        numbered = []
        for p in seq_dir.iterdir():
            m = _FRAME_RE.match(p.name)
            if m:
                numbered.append((int(m.group(1)), p))
        if not numbered:
            hint = " (pass sequence='seq-01' for a scene folder)" if any(seq_dir.glob("seq-*")) else ""
            raise SevenScenesError(f"no frame-XXXXXX.color.png in {seq_dir}; the sequence is empty{hint}")
        numbered.sort()
        self.root = seq_dir
        self.name = f"{seq_dir.parent.name}_{seq_dir.name}"
        self._numbers = [n for n, _ in numbered]
        self._color = [p for _, p in numbered]
        self._fps = float(fps)
        self.intrinsics = intrinsics.undistorted() if intrinsics is not None else SEVEN_SCENES_INTRINSICS
        # the published intrinsics are the depth camera's: nominal for the colour camera (mono calibrates them)
        self.intrinsics_nominal = intrinsics is None
        if intrinsics is not None and intrinsics.has_distortion:
            raise SevenScenesError(
                "7-Scenes images are used as pinhole images; give intrinsics without distortion"
            )
        self.has_depth = bool(with_depth)
        if with_depth:
            missing = [p for p in self._color if not self._depth_path(p).is_file()]
            if missing:
                raise SevenScenesError(
                    f"{len(missing)} depth files are missing, e.g. {self._depth_path(missing[0])}; "
                    "restore them or pass with_depth=False"
                )
        size = (self.intrinsics.width, self.intrinsics.height)
        check_image_files(self._color, size, "colour image")
        if with_depth:
            check_image_files([self._depth_path(p) for p in self._color], size, "depth map", depth=True)
        self._poses = [read_pose_txt(self._pose_path(p)) for p in self._color]
        idx = [i for i, T in enumerate(self._poses) if T is not None]
        self._gt: Trajectory | None = None
        if idx:
            self._gt = Trajectory(
                np.array([i / self._fps for i in idx]),
                np.stack([self._poses[i] for i in idx]),
                meta={"frame_indices": idx, "source": str(self.root)},
            )

    @staticmethod
    def _depth_path(color: Path) -> Path:
        return color.with_name(color.name.replace(".color.png", ".depth.png"))

    @staticmethod
    def _pose_path(color: Path) -> Path:
        return color.with_name(color.name.replace(".color.png", ".pose.txt"))

    def __len__(self) -> int:
        return len(self._color)

    def timestamps(self) -> list[float]:
        return [i / self._fps for i in range(len(self))]

    def __getitem__(self, index: int) -> Frame:
        i = normalize_index(index, len(self))
        image = read_color(self._color[i])
        h, w = image.shape[:2]
        if (w, h) != (self.intrinsics.width, self.intrinsics.height):
            raise SevenScenesError(
                f"{self._color[i]} is {w}x{h} but the intrinsics are for "
                f"{self.intrinsics.width}x{self.intrinsics.height}; pass matching intrinsics="
            )
        depth = None
        if self.has_depth:
            depth = read_depth(self._depth_path(self._color[i]), DEPTH_SCALE, INVALID_DEPTH)
            if depth.shape != (h, w):
                raise SevenScenesError(
                    f"{self._depth_path(self._color[i])} is {depth.shape[1]}x{depth.shape[0]} but the colour "
                    f"image is {w}x{h}; resize the depth to the colour resolution"
                )
        pose = None if self._poses[i] is None else self._poses[i].copy()
        return Frame(i, i / self._fps, image, self.intrinsics, depth, pose)

    def ground_truth(self) -> Trajectory | None:
        return self._gt

    def ground_truth_at_frames(self) -> Trajectory | None:
        """Same as :meth:`ground_truth`: 7-Scenes has one pose per frame."""
        return self.ground_truth()
