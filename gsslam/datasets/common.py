"""Small pieces every loader shares: text tables, timestamp checks, nearest-time association,
TUM-format poses, and the per-frame ground-truth bookkeeping.

Ground truth in every loader is exposed two ways:

- ``ground_truth()``: every ground-truth row of the dataset as a :class:`Trajectory` of
  ``T_world_cam`` (``None`` when the dataset has none);
- ``ground_truth_at_frames()``: only the frames that have a pose, at the *frame* timestamps, with
  ``meta["frame_indices"]`` naming the frames (``None`` when no frame has one). The same poses are
  ``frame.T_world_cam_gt``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from gsslam.datasets.base import DatasetError
from gsslam.io.trajectory import TrajectoryIOError, read_tum
from gsslam.types import CameraIntrinsics, Trajectory, TypesError


class DatasetFormatError(DatasetError):
    """A text file of a dataset (list, calibration, poses) is missing or malformed."""


def read_rows(path: Path, sep: str | None = None, what: str = "file") -> list[tuple[int, list[str]]]:
    """Non-empty, non-comment (``#``) lines of ``path`` split on ``sep``: ``[(line_number, fields)]``."""
    path = Path(path)
    if not path.is_file():
        raise DatasetFormatError(f"{what} is missing: {path}")
    rows = []
    with path.open("r", encoding="utf-8", errors="replace") as f:
        for n, line in enumerate(f, start=1):
            s = line.strip()
            if not s or s.startswith("#"):
                continue
            fields = [x.strip() for x in s.split(sep)] if sep else s.split()
            rows.append((n, fields))
    return rows


def parse_floats(fields: list[str], count: int, path: Path, line: int) -> np.ndarray:  # -> [count]
    if len(fields) < count:
        raise DatasetFormatError(
            f"{path}:{line}: expected {count} numbers, got {len(fields)}: {' '.join(fields)}"
        )
    try:
        values = np.array([float(x) for x in fields[:count]], dtype=np.float64)
    except ValueError:
        raise DatasetFormatError(f"{path}:{line}: not a number in: {' '.join(fields)}") from None
    if not np.all(np.isfinite(values)):
        raise DatasetFormatError(
            f"{path}:{line}: non-finite value (nan/inf) in: {' '.join(fields[:count])}; "
            "fix or delete this row"
        )
    return values


def check_increasing(timestamps: np.ndarray, source: Path | str, lines: list[int] | None = None) -> None:
    """Raise when ``timestamps`` [N] are not strictly increasing (unsorted or duplicate entries)."""
    t = np.asarray(timestamps)
    if len(t) < 2:
        return
    bad = np.flatnonzero(np.diff(t) <= 0)
    if len(bad):
        i = int(bad[0])
        where = f" (line {lines[i + 1]})" if lines else ""
        kind = "duplicate" if t[i + 1] == t[i] else "out-of-order"
        raise DatasetFormatError(
            f"{source}: {kind} timestamp {t[i + 1]!r}{where} after {t[i]!r}; "
            "timestamps must be strictly increasing: sort the file and remove duplicate rows"
        )


def associate_nearest(query: np.ndarray, ref: np.ndarray, max_dt: float) -> np.ndarray:
    """For each ``query`` time [N], the index of the nearest ``ref`` time [M] (sorted) within
    ``max_dt`` seconds, or -1. Returns [N] int64."""
    query = np.asarray(query, dtype=np.float64)
    ref = np.asarray(ref, dtype=np.float64)
    out = np.full(len(query), -1, dtype=np.int64)
    if len(ref) == 0 or len(query) == 0:
        return out
    hi = np.clip(np.searchsorted(ref, query), 1, len(ref) - 1) if len(ref) > 1 else np.zeros(len(query), int)
    lo = np.maximum(hi - 1, 0)
    pick = np.where(np.abs(ref[lo] - query) <= np.abs(ref[hi] - query), lo, hi)
    ok = np.abs(ref[pick] - query) <= max_dt
    out[ok] = pick[ok]
    return out


def read_tum_trajectory(path: Path, what: str = "trajectory") -> Trajectory:
    """A TUM-format file ``timestamp tx ty tz qx qy qz qw`` (``#`` comments) as a Trajectory, read by
    the one TUM parser (``gsslam.io.trajectory.read_tum``); timestamps must be strictly increasing."""
    path = Path(path)
    if not path.is_file():
        raise DatasetFormatError(f"{what} is missing: {path}")
    try:
        traj = read_tum(path)
    except TrajectoryIOError as e:
        raise DatasetFormatError(f"{what}: {e}; fix the file or delete that row") from None
    check_increasing(traj.timestamps, path)
    return Trajectory(traj.timestamps, traj.poses, meta={"source": str(path)})


class FrameGroundTruth:
    """Per-frame ground truth: ``gt_index[i]`` is the row of ``trajectory`` for frame i, or -1."""

    def __init__(self, trajectory: Trajectory | None, gt_index: np.ndarray | None) -> None:
        self.trajectory = trajectory
        self.gt_index = gt_index

    @classmethod
    def by_time(
        cls, trajectory: Trajectory | None, frame_times: np.ndarray, max_dt: float
    ) -> FrameGroundTruth:
        if trajectory is None:
            return cls(None, None)
        return cls(trajectory, associate_nearest(frame_times, trajectory.timestamps, max_dt))

    def pose(self, i: int) -> np.ndarray | None:  # -> [4, 4] or None
        if self.trajectory is None or self.gt_index[i] < 0:
            return None
        return self.trajectory.poses[self.gt_index[i]].copy()

    def at_frames(self, frame_times: np.ndarray) -> Trajectory | None:
        if self.trajectory is None:
            return None
        idx = np.flatnonzero(self.gt_index >= 0)
        if len(idx) == 0:
            return None
        return Trajectory(
            np.asarray(frame_times)[idx],
            self.trajectory.poses[self.gt_index[idx]],
            meta={**self.trajectory.meta, "frame_indices": idx.tolist()},
        )


def normalize_index(index: int, n: int) -> int:
    """Python-style index into a sequence of ``n`` frames; IndexError when out of range."""
    if not isinstance(index, (int, np.integer)):
        raise TypeError(f"frame index must be an integer, got {type(index).__name__}")
    i = int(index)
    if i < 0:
        i += n
    if not 0 <= i < n:
        raise IndexError(f"frame index {index} out of range for {n} frames")
    return i


def read_yaml_mapping(path: Path, what: str, keys: str) -> dict:
    """A YAML file that must hold a mapping; binary or malformed files raise with the file named."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise DatasetFormatError(
            f"{what} {path} is not a text file (binary data?); write a YAML mapping with {keys}"
        ) from None
    except OSError as e:
        raise DatasetFormatError(f"cannot read {what} {path}: {e.strerror}") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as e:
        first = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise DatasetFormatError(
            f"{what} {path} is not valid YAML ({first}); write a mapping with {keys}"
        ) from None
    if not isinstance(data, dict):
        raise DatasetFormatError(f"{what} {path} must be a YAML mapping with keys {keys}")
    return data


# ROS names of OpenCV's k1 k2 p1 p2 [k3 ...] distortion
OPENCV_DISTORTION_MODELS = ("plumb_bob", "rational_polynomial", "")


def ros_camera_info_yaml(data: dict, path: Path | str) -> dict:
    """``fx fy cx cy width height distortion`` from a ROS camera_info YAML (``camera_matrix.data``
    row-major 3x3, ``distortion_model``, ``distortion_coefficients.data``, ``image_width/height``)."""
    try:
        K = [float(v) for v in data["camera_matrix"]["data"]]
        dist = [float(v) for v in (data.get("distortion_coefficients") or {}).get("data") or ()]
    except (KeyError, TypeError, ValueError) as e:
        raise DatasetFormatError(
            f"intrinsics file {path}: camera_matrix needs 'data: [fx, 0, cx, 0, fy, cy, 0, 0, 1]' ({e})"
        ) from None
    if len(K) != 9:
        raise DatasetFormatError(f"intrinsics file {path}: camera_matrix.data has {len(K)} values, not 9")
    model = str(data.get("distortion_model") or "")
    if model not in OPENCV_DISTORTION_MODELS and any(dist):
        raise DatasetFormatError(
            f"intrinsics file {path}: distortion_model '{model}' is not supported; "
            f"use one of {', '.join(m for m in OPENCV_DISTORTION_MODELS if m)} or rectified images"
        )
    out = {"fx": K[0], "fy": K[4], "cx": K[2], "cy": K[5], "distortion": dist if any(dist) else []}
    if "image_width" in data and "image_height" in data:
        out.update(width=data["image_width"], height=data["image_height"])
    return out


def load_intrinsics_yaml(path: Path, width: int | None = None, height: int | None = None) -> CameraIntrinsics:
    """Intrinsics from a YAML file with ``fx, fy, cx, cy`` and optional ``distortion``, ``width``,
    ``height``, or a ROS camera_info YAML (:func:`ros_camera_info_yaml`); the size falls back to
    ``width``/``height`` given here."""
    path = Path(path)
    if not path.is_file():
        raise DatasetFormatError(f"intrinsics file is missing: {path}")
    data = read_yaml_mapping(path, "intrinsics file", "fx, fy, cx, cy")
    if "camera_matrix" in data:
        data = ros_camera_info_yaml(data, path)
    missing = [k for k in ("fx", "fy", "cx", "cy") if k not in data]
    if missing:
        raise DatasetFormatError(
            f"intrinsics file {path} lacks {', '.join(missing)}; give fx, fy, cx, cy in pixels"
        )
    w = data.get("width", width)
    h = data.get("height", height)
    if w is None or h is None:
        raise DatasetFormatError(f"intrinsics file {path}: add width and height (pixels)")
    try:
        dist = tuple(float(d) for d in (data.get("distortion") or ()))
        return CameraIntrinsics(
            float(data["fx"]), float(data["fy"]), float(data["cx"]), float(data["cy"]), int(w), int(h), dist
        )
    except (TypeError, ValueError) as e:
        raise DatasetFormatError(f"intrinsics file {path}: bad value ({e}); use numbers") from None
    except TypesError as e:
        raise DatasetFormatError(f"intrinsics file {path}: {e}") from None
