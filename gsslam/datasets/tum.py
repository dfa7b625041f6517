"""TUM RGB-D benchmark sequences (``rgb.txt``, ``depth.txt``, ``groundtruth.txt``).

Sturm et al., "A Benchmark for the Evaluation of RGB-D SLAM Systems", IROS 2012.

- Frames are the entries of ``rgb.txt``, in file order (timestamps must be strictly increasing).
- Depth: each rgb frame gets the nearest ``depth.txt`` entry within ``max_dt`` seconds (default
  0.02 s, as TUM's ``associate.py``); depth PNG value / 5000 = metres, 0 = NaN. A frame with no
  depth within ``max_dt`` is handled by ``missing_depth``: ``"skip"`` (default: the frame is dropped,
  as ``associate.py`` does, so every frame has depth), ``"none"`` (kept with ``depth=None``) or
  ``"error"``. ``with_depth=False`` ignores depth entirely (monocular use).
- Intrinsics: the published calibration of the Freiburg 1/2/3 sensor named in the folder
  (``freiburg1``/``fr1`` ...), or ``intrinsics=CameraIntrinsics`` / ``intrinsics_file=`` (YAML with
  ``fx, fy, cx, cy[, distortion, width, height]``). fr1/fr2 images are distorted: the loader
  undistorts colour and depth once and hands out frames with the same K and no distortion.
- Ground truth: ``groundtruth.txt`` (camera pose in the mocap world). ``ground_truth()`` gives every
  row; a frame's ``T_world_cam_gt`` is the nearest row within ``max_dt`` (else ``None``; fr3/teddy's
  first 5 frames come before the first pose).
- IMU: TUM RGB-D has none. ``imu="synthesized"`` makes :meth:`TumRgbdDataset.imu` return 200 Hz samples
  *synthesized* from the ground truth (:mod:`gsslam.datasets.imu_synth`: smoothing spline, EuRoC imu0
  noise and bias random walk, seeded by ``imu_seed``); the body frame is the camera
  (``T_body_cam = I``). Label every number made with them "synthesized".
"""

from __future__ import annotations

import logging
import re
from pathlib import Path

import numpy as np

from gsslam.datasets.base import DatasetError
from gsslam.datasets.common import (
    FrameGroundTruth,
    associate_nearest,
    check_increasing,
    load_intrinsics_yaml,
    normalize_index,
    parse_floats,
    read_rows,
    read_tum_trajectory,
)
from gsslam.datasets.image_io import Undistorter, check_image_files, read_color, read_depth
from gsslam.types import CameraIntrinsics, Frame, ImuSamples, Trajectory

log = logging.getLogger(__name__)

DEPTH_SCALE = 5000.0  # TUM depth PNG value per metre
# Published TUM calibrations (https://cvg.cit.tum.de/data/datasets/rgbd-dataset/file_formats), 640x480.
TUM_INTRINSICS = {
    1: CameraIntrinsics(517.3, 516.5, 318.6, 255.3, 640, 480, (0.2624, -0.9531, -0.0054, 0.0026, 1.1633)),
    2: CameraIntrinsics(520.9, 521.0, 325.1, 249.7, 640, 480, (0.2312, -0.7849, -0.0033, -0.0001, 0.9172)),
    3: CameraIntrinsics(535.4, 539.2, 320.1, 247.6, 640, 480, ()),
}
MISSING_DEPTH_MODES = ("skip", "none", "error")


class TumError(DatasetError):
    """A TUM RGB-D folder is incomplete or inconsistent."""


def tum_sensor_from_name(name: str) -> int | None:
    """1, 2 or 3 when ``name`` contains ``freiburgN`` or ``frN`` (case-insensitive), else None."""
    m = re.search(r"(?:freiburg|(?<![a-z])fr)([123])(?![0-9])", name.lower())
    return int(m.group(1)) if m else None


def _read_list(path: Path, what: str) -> tuple[np.ndarray, list[str]]:
    rows = read_rows(path, what=what)
    times = np.array([parse_floats(f, 1, path, n)[0] for n, f in rows], dtype=np.float64)
    for n, f in rows:
        if len(f) < 2:
            raise TumError(f"{path}:{n}: expected 'timestamp filename', got '{' '.join(f)}'")
    check_increasing(times, path, [n for n, _ in rows])
    return times, [f[1] for _, f in rows]


class TumRgbdDataset:
    """A TUM RGB-D sequence folder; see the module docstring for the kwargs."""

    def __init__(
        self,
        path: str | Path,
        *,
        max_dt: float = 0.02,
        intrinsics: CameraIntrinsics | None = None,
        intrinsics_file: str | Path | None = None,
        with_depth: bool = True,
        missing_depth: str = "skip",
        gt_path: str | Path | None = None,
        imu: str | None = None,
        imu_seed: int = 0,
    ) -> None:
        self.root = Path(path)
        if not self.root.is_dir():
            raise TumError(f"TUM sequence folder does not exist: {self.root}")
        if missing_depth not in MISSING_DEPTH_MODES:
            raise TumError(f"missing_depth must be one of {MISSING_DEPTH_MODES}, got {missing_depth!r}")
        self.name = self.root.name
        self.max_dt = float(max_dt)
        if imu not in (None, "synthesized"):
            raise TumError(f"imu must be None or 'synthesized' (TUM RGB-D has no IMU), got {imu!r}")
        self._imu_mode, self._imu_seed, self._imu = imu, int(imu_seed), None
        self.T_body_cam = np.eye(4)  # the (synthesized) IMU sits in the camera frame

        if intrinsics is None and intrinsics_file is not None:
            intrinsics = load_intrinsics_yaml(Path(intrinsics_file), 640, 480)
        if intrinsics is None:
            sensor = tum_sensor_from_name(self.root.resolve().name)
            if sensor is None:
                raise TumError(
                    f"cannot tell the TUM sensor from the folder name '{self.root.name}'; "
                    "keep 'freiburg1/2/3' in the name or pass intrinsics=CameraIntrinsics(...) "
                    "or intrinsics_file=..."
                )
            intrinsics = TUM_INTRINSICS[sensor]
        self._undistort = Undistorter(intrinsics)
        self.intrinsics = self._undistort.intrinsics_out

        rgb_t, rgb_files = _read_list(self.root / "rgb.txt", "TUM rgb.txt")
        if len(rgb_t) == 0:
            raise TumError(f"{self.root / 'rgb.txt'} lists no images; the sequence is empty")
        keep = np.arange(len(rgb_t))
        depth_files: list[str | None] = [None] * len(rgb_t)
        self.has_depth = bool(with_depth)
        if with_depth:
            d_t, d_files = _read_list(
                self.root / "depth.txt", "TUM depth.txt (use with_depth=False for RGB only)"
            )
            match = associate_nearest(rgb_t, d_t, self.max_dt)
            unmatched = np.flatnonzero(match < 0)
            if len(unmatched):
                msg = f"{len(unmatched)} of {len(rgb_t)} rgb frames have no depth within {self.max_dt} s"
                if missing_depth == "error":
                    raise TumError(f"{self.root}: {msg}; raise max_dt or use missing_depth='skip'/'none'")
                log.warning("%s: %s (missing_depth=%s)", self.root, msg, missing_depth)
                if missing_depth == "skip":
                    keep = np.flatnonzero(match >= 0)
            depth_files = [d_files[m] if m >= 0 else None for m in match]
            if len(keep) == 0:
                raise TumError(f"{self.root}: no rgb frame has a depth map within {self.max_dt} s")
        self._times = rgb_t[keep]
        self._rgb = [rgb_files[k] for k in keep]
        self._depth = [depth_files[k] for k in keep]
        # headers only: an odd-sized or 8-bit depth file is refused now, not when the run reaches it
        size = (intrinsics.width, intrinsics.height)
        check_image_files([self.root / f for f in self._rgb], size, "rgb image")
        check_image_files(
            [self.root / f for f in self._depth if f is not None], size, "depth map", depth=True
        )

        gt_file = Path(gt_path) if gt_path is not None else self.root / "groundtruth.txt"
        traj: Trajectory | None = None
        if gt_file.is_file():
            traj = read_tum_trajectory(gt_file, "TUM groundtruth")
        elif gt_path is not None:
            raise TumError(f"ground-truth file is missing: {gt_file}")
        self._gt = FrameGroundTruth.by_time(traj, self._times, self.max_dt)
        log.info("TUM %s: %d frames, depth=%s, gt=%s", self.name, len(self), self.has_depth, traj is not None)

    def __len__(self) -> int:
        return len(self._times)

    def timestamps(self) -> list[float]:
        return self._times.tolist()

    def __getitem__(self, index: int) -> Frame:
        i = normalize_index(index, len(self))
        image = self._undistort.image(read_color(self.root / self._rgb[i]))
        depth = None
        if self._depth[i] is not None:
            raw = read_depth(self.root / self._depth[i], DEPTH_SCALE)
            if raw.shape != image.shape[:2]:
                raise TumError(
                    f"depth {self._depth[i]} is {raw.shape[1]}x{raw.shape[0]} but rgb {self._rgb[i]} is "
                    f"{image.shape[1]}x{image.shape[0]}; depth must be registered to the rgb image"
                )
            depth = self._undistort.depth(raw)
        return Frame(i, float(self._times[i]), image, self.intrinsics, depth, self._gt.pose(i))

    def ground_truth(self) -> Trajectory | None:
        return self._gt.trajectory

    def ground_truth_at_frames(self) -> Trajectory | None:
        return self._gt.at_frames(self._times)

    def imu(self) -> ImuSamples:
        """IMU samples *synthesized* from the ground truth (``imu="synthesized"``); see the module doc."""
        if self._imu_mode is None:
            raise TumError(
                f"{self.root}: TUM RGB-D has no IMU; open it with imu='synthesized' "
                "(--dataset-arg imu=synthesized) to synthesize one from the ground truth"
            )
        gt = self._gt.trajectory
        if gt is None:
            raise TumError(f"{self.root}: IMU synthesis needs groundtruth.txt")
        if self._imu is None:
            from gsslam.datasets.imu_synth import synthesize_imu

            t_range = (self._times[0] - 1.0, self._times[-1] + 1.0)
            self._imu = synthesize_imu(gt.timestamps, gt.poses, seed=self._imu_seed, t_range=t_range).samples
        return self._imu
