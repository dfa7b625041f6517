"""KITTI odometry sequences (``sequences/XX/image_N``, ``calib.txt``, ``times.txt``, ``poses/XX.txt``).

Geiger et al., "Are we ready for autonomous driving? The KITTI vision benchmark suite", CVPR 2012.

- ``path``: the dataset root (holding ``sequences/`` and ``poses/``) together with
  ``sequence="06"``, or the ``sequences/06`` folder itself.
- ``camera``: 0 (left gray, default), 1 (right gray), 2 / 3 (colour); images ``image_<camera>/*.png``
  sorted by name, frame i is the file named ``i`` (``000042.png`` is frame 42's row in times/poses).
  Grayscale images are replicated to RGB. KITTI images are rectified: no distortion.
- Calibration: ``calib.txt`` (``P0: ...`` labelled rows) or, failing that, ``calib_P0_P1.txt``
  (unlabelled rows P0, P1, ...). K is the left 3x3 of ``P<camera>``.
- ``times.txt`` gives timestamps (s); without it frames are ``i / fps`` apart (``fps=10.0``).
- Ground truth ``<root>/poses/XX.txt`` (or ``gt_path=``): row i maps camera-0 points of frame i to
  the camera-0 frame of frame 0, so frame 0 is the identity. For ``camera != 0`` the loader moves it
  to that camera with the baseline in ``P<camera>``. ``ground_truth()`` holds every row.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from gsslam.datasets.base import DatasetError
from gsslam.datasets.common import (
    FrameGroundTruth,
    check_increasing,
    normalize_index,
    parse_floats,
    read_rows,
)
from gsslam.datasets.image_io import check_image_files, read_color
from gsslam.geometry import invert_T
from gsslam.types import CameraIntrinsics, Frame, Trajectory

log = logging.getLogger(__name__)


class KittiError(DatasetError):
    """A KITTI odometry folder, calibration or pose file is missing or malformed."""


def read_kitti_calib(seq_dir: Path) -> dict[str, np.ndarray]:
    """Projection matrices ``{"P0": [3, 4], ...}`` from ``calib.txt`` or ``calib_P0_P1.txt``."""
    for name in ("calib.txt", "calib_P0_P1.txt"):
        path = seq_dir / name
        if not path.is_file():
            continue
        out: dict[str, np.ndarray] = {}
        for k, (n, fields) in enumerate(read_rows(path, what="KITTI calibration")):
            if fields[0].endswith(":"):
                label, fields = fields[0][:-1], fields[1:]
            else:
                label = f"P{k}"
            if len(fields) == 12:
                out[label] = parse_floats(fields, 12, path, n).reshape(3, 4)
            elif label.startswith("P"):
                raise KittiError(f"{path}:{n}: {label} must have 12 numbers, got {len(fields)}")
        if not out:
            raise KittiError(f"{path} holds no projection matrix")
        return out
    raise KittiError(
        f"{seq_dir} has neither calib.txt nor calib_P0_P1.txt; copy the sequence's calib.txt there"
    )


def read_kitti_poses(path: Path) -> np.ndarray:  # -> [N, 4, 4]
    rows = read_rows(path, what="KITTI poses")
    if not rows:
        raise KittiError(f"pose file {path} is empty")
    T = np.tile(np.eye(4), (len(rows), 1, 1))
    for k, (n, fields) in enumerate(rows):
        if len(fields) != 12:
            raise KittiError(f"{path}:{n}: a KITTI pose is 12 numbers (3x4 row-major), got {len(fields)}")
        T[k, :3, :] = parse_floats(fields, 12, path, n).reshape(3, 4)
    return T


class KittiOdometryDataset:
    """One KITTI odometry sequence; see the module docstring for the kwargs."""

    def __init__(
        self,
        path: str | Path,
        *,
        sequence: str | int | None = None,
        camera: int = 0,
        fps: float = 10.0,
        gt_path: str | Path | None = None,
    ) -> None:
        path = Path(path)
        if sequence is not None:
            seq = f"{int(sequence):02d}" if str(sequence).isdigit() else str(sequence)
            root, seq_dir = path, path / "sequences" / seq
        elif path.parent.name == "sequences":
            seq, root, seq_dir = path.name, path.parent.parent, path
        else:
            raise KittiError(
                f"{path}: pass the sequences/XX folder, or the dataset root together with sequence='XX'"
            )
        if not seq_dir.is_dir():
            raise KittiError(f"KITTI sequence folder does not exist: {seq_dir}")
        if camera not in (0, 1, 2, 3):
            raise KittiError(f"camera must be 0, 1, 2 or 3, got {camera}")
        self.root, self.seq_dir, self.sequence, self.camera = root, seq_dir, seq, camera
        self.name = f"kitti_{seq}"
        self.has_depth = False

        img_dir = seq_dir / f"image_{camera}"
        self._files = sorted(img_dir.glob("*.png")) if img_dir.is_dir() else []
        if not self._files:
            raise KittiError(f"no PNG images in {img_dir}; the sequence is empty or the camera is not there")
        try:
            self._rows = np.array([int(f.stem) for f in self._files], dtype=np.int64)
        except ValueError:
            raise KittiError(f"{img_dir}: image names must be frame numbers like 000042.png") from None
        check_increasing(self._rows, img_dir)

        P = read_kitti_calib(seq_dir).get(f"P{camera}")
        if P is None:
            raise KittiError(f"{seq_dir}: the calibration has no P{camera}")
        w, h = check_image_files(self._files, None, "image")  # headers only, before any run
        self.intrinsics = CameraIntrinsics(
            float(P[0, 0]), float(P[1, 1]), float(P[0, 2]), float(P[1, 2]), w, h
        )
        # P_i = K [I | t_i]: points in camera i are camera-0 points plus t_i.
        self.T_cam0_cam = np.eye(4)
        self.T_cam0_cam[:3, 3] = -np.linalg.solve(P[:, :3], P[:, 3])

        times_file = seq_dir / "times.txt"
        n_needed = int(self._rows.max()) + 1
        if times_file.is_file():
            rows = read_rows(times_file, what="KITTI times.txt")
            all_times = np.array([parse_floats(f, 1, times_file, n)[0] for n, f in rows])
            check_increasing(all_times, times_file, [n for n, _ in rows])
            if len(all_times) < n_needed:
                raise KittiError(f"{times_file} has {len(all_times)} rows but image {n_needed - 1} exists")
        else:
            log.warning("%s: no times.txt; using frame index / %.3g Hz", seq_dir, fps)
            all_times = None
        self._fps = float(fps)
        self._times = all_times[self._rows] if all_times is not None else self._rows / self._fps

        gt_file = Path(gt_path) if gt_path is not None else root / "poses" / f"{seq}.txt"
        traj = None
        if gt_file.is_file():
            # world = this camera at frame 0; identity change for camera 0
            T = invert_T(self.T_cam0_cam) @ read_kitti_poses(gt_file) @ self.T_cam0_cam
            if all_times is not None and len(all_times) >= len(T):
                t = all_times[: len(T)]
            else:
                t = np.arange(len(T)) / self._fps
            traj = Trajectory(t, T, meta={"source": str(gt_file)})
            if len(T) < n_needed:
                raise KittiError(f"{gt_file} has {len(T)} poses but image {n_needed - 1} exists")
        elif gt_path is not None:
            raise KittiError(f"ground-truth file is missing: {gt_file}")
        self._gt = FrameGroundTruth(traj, self._rows.copy() if traj is not None else None)
        log.info("KITTI %s: %d frames, gt=%s", seq, len(self), traj is not None)

    def __len__(self) -> int:
        return len(self._files)

    def timestamps(self) -> list[float]:
        return np.asarray(self._times, dtype=np.float64).tolist()

    def __getitem__(self, index: int) -> Frame:
        i = normalize_index(index, len(self))
        image = read_color(self._files[i])
        h, w = image.shape[:2]
        if (w, h) != (self.intrinsics.width, self.intrinsics.height):
            raise KittiError(
                f"{self._files[i]} is {w}x{h} but {self._files[0].name} is "
                f"{self.intrinsics.width}x{self.intrinsics.height}; all images of a sequence must match"
            )
        return Frame(i, float(self._times[i]), image, self.intrinsics, None, self._gt.pose(i))

    def ground_truth(self) -> Trajectory | None:
        return self._gt.trajectory

    def ground_truth_at_frames(self) -> Trajectory | None:
        return self._gt.at_frames(np.asarray(self._times, dtype=np.float64))
