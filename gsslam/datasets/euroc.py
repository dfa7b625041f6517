"""EuRoC MAV sequences in the ASL layout (``mav0/cam0``, ``mav0/imu0``, ground truth).

Burri et al., "The EuRoC micro aerial vehicle datasets", IJRR 2016.

- ``path``: the sequence folder holding ``mav0/`` (or ``mav0`` itself).
- Frames: ``mav0/cam0/data.csv`` rows (``timestamp [ns], filename``), grayscale PNGs replicated to
  RGB. Timestamps are seconds as float64; the exact integer nanoseconds are ``timestamps_ns()``.
- Intrinsics and radial-tangential distortion from ``mav0/cam0/sensor.yaml``; images are undistorted
  once and frames carry the same K with no distortion. ``T_body_cam`` is the sensor's ``T_BS``.
- IMU: :meth:`EurocDataset.imu` reads ``mav0/imu0/data.csv`` (gyro rad/s, accel m/s^2, in the IMU
  frame, which is the body frame in EuRoC) with the noise densities of ``imu0/sensor.yaml``.
- Ground truth is a *body* trajectory ``T_W_B``; the loader hands out camera poses
  ``T_W_cam = T_W_B @ T_BS``. Source, in order: ``gt_path=`` (an EuRoC csv
  ``t_ns, px, py, pz, qw, qx, qy, qz, ...`` or a TUM file ``t tx ty tz qx qy qz qw``, told apart by
  the commas), ``mav0/state_groundtruth_estimate0/data.csv``, else a sibling folder
  ``<sequence folder name>_groundtruth/`` holding exactly one ``*.csv`` or, failing that, one
  ``*.txt`` in TUM format. A frame's ``T_world_cam_gt`` is the nearest pose within ``max_dt``
  seconds (default 0.01 s), else ``None``.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import yaml

from gsslam.datasets.base import DatasetError
from gsslam.datasets.common import (
    FrameGroundTruth,
    check_increasing,
    normalize_index,
    parse_floats,
    read_rows,
    read_tum_trajectory,
)
from gsslam.datasets.image_io import Undistorter, check_image_files, read_color
from gsslam.geometry import make_T, quat_to_rot
from gsslam.types import CameraIntrinsics, Frame, ImuSamples, Trajectory

log = logging.getLogger(__name__)


class EurocError(DatasetError):
    """A EuRoC folder, calibration or csv file is missing or malformed."""


def ns_to_s(t_ns: np.ndarray) -> np.ndarray:  # [N] int64 -> [N] float64
    """Nanoseconds to seconds, splitting whole seconds first so the float64 is correctly rounded."""
    t_ns = np.asarray(t_ns, dtype=np.int64)
    return (t_ns // 1_000_000_000).astype(np.float64) + (t_ns % 1_000_000_000).astype(np.float64) * 1e-9


def read_sensor_yaml(path: Path) -> dict:
    """An ASL ``sensor.yaml`` (OpenCV-flavoured YAML: ``%YAML:1.0`` header, optional matrix tags)."""
    if not path.is_file():
        raise EurocError(f"EuRoC sensor calibration is missing: {path}")
    try:
        raw = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise EurocError(
            f"{path} is not a text file (binary data?); restore the sequence's sensor.yaml"
        ) from None
    text = "\n".join(l for l in raw.splitlines() if not l.startswith("%"))
    text = text.replace("!!opencv-matrix", "")
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as e:
        raise EurocError(f"{path} is not valid YAML: {e}") from None
    if not isinstance(data, dict):
        raise EurocError(f"{path} must be a YAML mapping")
    return data


def _matrix(data: dict, key: str, path: Path) -> np.ndarray:  # -> [4, 4]
    m = data.get(key)
    try:
        T = np.asarray(m["data"], dtype=np.float64).reshape(int(m["rows"]), int(m["cols"]))
    except (TypeError, KeyError, ValueError):
        raise EurocError(f"{path}: '{key}' must be a 4x4 matrix with rows, cols and data") from None
    if T.shape != (4, 4):
        raise EurocError(f"{path}: '{key}' must be 4x4, got {T.shape}")
    return T


def _read_ns_csv(path: Path, min_cols: int, what: str) -> tuple[np.ndarray, list[list[str]], list[int]]:
    rows = read_rows(path, sep=",", what=what)
    try:
        t_ns = np.array([int(f[0]) for _, f in rows], dtype=np.int64)
    except ValueError:
        raise EurocError(f"{path}: the first column must be integer nanoseconds") from None
    lines = [n for n, _ in rows]
    for n, f in rows:
        if len(f) < min_cols:
            raise EurocError(f"{path}:{n}: expected {min_cols} comma-separated columns, got {len(f)}")
    check_increasing(t_ns, path, lines)
    return t_ns, [f for _, f in rows], lines


def read_euroc_gt_csv(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """EuRoC ground-truth csv ``t_ns, px, py, pz, qw, qx, qy, qz, ...`` -> (t_ns [N], T_W_B [N, 4, 4])."""
    t_ns, rows, lines = _read_ns_csv(path, 8, "EuRoC ground truth")
    if len(t_ns) == 0:
        raise EurocError(f"ground-truth file {path} has no poses")
    vals = np.stack([parse_floats(f[1:8], 7, path, n) for f, n in zip(rows, lines)])
    q_xyzw = vals[:, [4, 5, 6, 3]]
    poses = np.stack([make_T(quat_to_rot(q), p) for q, p in zip(q_xyzw, vals[:, :3])])
    return t_ns, poses


def _find_gt(root: Path) -> Path | None:
    asl = root / "mav0" / "state_groundtruth_estimate0" / "data.csv"
    if asl.is_file():
        return asl
    sibling = root.parent / f"{root.name}_groundtruth"
    if sibling.is_dir():
        for pattern in ("*.csv", "*.txt"):
            found = sorted(sibling.glob(pattern))
            if len(found) == 1:
                return found[0]
            if len(found) > 1:
                log.warning("%s holds several %s files; pass gt_path= to choose one", sibling, pattern)
                return None
    return None


class EurocDataset:
    """A EuRoC MAV sequence (cam0 only); see the module docstring for the kwargs."""

    def __init__(
        self,
        path: str | Path,
        *,
        camera: str = "cam0",
        gt_path: str | Path | None = None,
        max_dt: float = 0.01,
    ) -> None:
        root = Path(path)
        if root.name == "mav0":
            root = root.parent
        self.root = root
        self.mav0 = root / "mav0"
        if not self.mav0.is_dir():
            raise EurocError(f"{root} has no mav0/ folder; point to the EuRoC sequence folder (ASL layout)")
        self.name = root.name
        self.has_depth = False
        self.max_dt = float(max_dt)
        cam_dir = self.mav0 / camera

        calib = read_sensor_yaml(cam_dir / "sensor.yaml")
        self.T_body_cam = _matrix(calib, "T_BS", cam_dir / "sensor.yaml")
        model = calib.get("distortion_model", "radial-tangential")
        if calib.get("camera_model", "pinhole") != "pinhole" or model not in ("radial-tangential", "radtan"):
            raise EurocError(
                f"{cam_dir / 'sensor.yaml'}: only pinhole + radial-tangential cameras are supported, "
                f"got {calib.get('camera_model')} + {model}"
            )
        try:
            fx, fy, cx, cy = (float(v) for v in calib["intrinsics"])
            w, h = (int(v) for v in calib["resolution"])
            dist = tuple(float(d) for d in calib.get("distortion_coefficients") or ())
        except (KeyError, TypeError, ValueError):
            raise EurocError(
                f"{cam_dir / 'sensor.yaml'}: needs intrinsics [fu, fv, cu, cv] and resolution [w, h]"
            ) from None
        self._undistort = Undistorter(CameraIntrinsics(fx, fy, cx, cy, w, h, dist))
        self.intrinsics = self._undistort.intrinsics_out

        self._t_ns, rows, _ = _read_ns_csv(cam_dir / "data.csv", 2, f"EuRoC {camera}/data.csv")
        if len(self._t_ns) == 0:
            raise EurocError(f"{cam_dir / 'data.csv'} lists no images; the sequence is empty")
        self._files = [cam_dir / "data" / f[1] for f in rows]
        check_image_files(self._files, (w, h), "image")  # headers only, before any run
        self._times = ns_to_s(self._t_ns)

        gt_file = Path(gt_path) if gt_path is not None else _find_gt(root)
        traj = self._load_gt(gt_file) if gt_file is not None else None
        self._gt = FrameGroundTruth.by_time(traj, self._times, self.max_dt)
        log.info("EuRoC %s: %d frames, gt=%s", self.name, len(self), gt_file)

    def _load_gt(self, path: Path) -> Trajectory:
        if not path.is_file():
            raise EurocError(f"ground-truth file is missing: {path}")
        with path.open() as f:
            first = next((l for l in f if l.strip() and not l.startswith("#")), "")
        if "," in first:
            t_ns, T_W_B = read_euroc_gt_csv(path)
            t = ns_to_s(t_ns)
        else:
            body = read_tum_trajectory(path, "EuRoC ground truth (TUM format)")
            t, T_W_B = body.timestamps, body.poses
        return Trajectory(
            t, T_W_B @ self.T_body_cam, meta={"source": str(path), "frame": "cam0 = body @ T_BS"}
        )

    def __len__(self) -> int:
        return len(self._times)

    def timestamps(self) -> list[float]:
        return self._times.tolist()

    def timestamps_ns(self) -> np.ndarray:  # [N] int64
        return self._t_ns.copy()

    def __getitem__(self, index: int) -> Frame:
        i = normalize_index(index, len(self))
        image = self._undistort.image(read_color(self._files[i]))
        return Frame(i, float(self._times[i]), image, self.intrinsics, None, self._gt.pose(i))

    def ground_truth(self) -> Trajectory | None:
        return self._gt.trajectory

    def ground_truth_at_frames(self) -> Trajectory | None:
        return self._gt.at_frames(self._times)

    def imu(self) -> ImuSamples:
        """All samples of ``mav0/imu0/data.csv``; raises when the sequence has no IMU."""
        imu_dir = self.mav0 / "imu0"
        t_ns, rows, lines = _read_ns_csv(imu_dir / "data.csv", 7, "EuRoC imu0/data.csv")
        if len(t_ns) == 0:
            raise EurocError(f"{imu_dir / 'data.csv'} has no samples")
        vals = np.stack([parse_floats(f[1:7], 6, imu_dir / "data.csv", n) for f, n in zip(rows, lines)])
        noise: dict = {}
        T_body_imu = np.eye(4)
        if (imu_dir / "sensor.yaml").is_file():
            calib = read_sensor_yaml(imu_dir / "sensor.yaml")
            keys = ("gyroscope_noise_density", "gyroscope_random_walk", "accelerometer_noise_density",
                    "accelerometer_random_walk", "rate_hz")  # fmt: skip
            noise = {k: float(calib[k]) for k in keys if k in calib}
            if "T_BS" in calib:
                T_body_imu = _matrix(calib, "T_BS", imu_dir / "sensor.yaml")
        return ImuSamples(ns_to_s(t_ns), t_ns, vals[:, 0:3].copy(), vals[:, 3:6].copy(), noise, T_body_imu)
