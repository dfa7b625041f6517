"""Core value types shared by every stage: camera intrinsics, frames and trajectories.

Conventions (see docs/conventions.md):
- ``T_a_b`` is a 4x4 homogeneous matrix mapping points in frame b to frame a.
- Camera frames are OpenCV-style: x right, y down, z forward; units are metres and seconds.
- Images are ``[H, W, 3]`` float32 RGB in [0, 1]; depth is ``[H, W]`` float32 metres with
  invalid pixels set to NaN.
- Quaternions at file boundaries are (qx, qy, qz, qw) as in the TUM format.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from gsslam.compact import CodedField, PointMapField
from gsslam.errors import GsslamError

StageProgress = Callable[[str, int, int], None]
"""``(stage, done, total)``: progress of a long stage ("final pass", "batch refinement", "outputs", ...).

The library calls it (and logs at INFO what each stage does); only the CLI draws bars from it.
"""


class TypesError(GsslamError):
    """A value does not have the shape or content a core type needs."""


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics with optional OpenCV distortion (k1, k2, p1, p2[, k3...]).

    Loaders undistort images once when ``distortion`` is non-zero and hand out frames whose
    intrinsics have ``distortion == ()`` (see docs/conventions.md).
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    distortion: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        if not (self.fx > 0 and self.fy > 0) or not np.isfinite([self.fx, self.fy]).all():
            raise TypesError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        if not np.isfinite([self.cx, self.cy]).all():
            raise TypesError(f"principal point must be finite, got cx={self.cx}, cy={self.cy}")
        if self.width <= 0 or self.height <= 0:
            raise TypesError(f"image size must be positive, got {self.width}x{self.height}")

    @property
    def K(self) -> np.ndarray:  # [3, 3]
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def has_distortion(self) -> bool:
        return any(abs(d) > 0 for d in self.distortion)

    def scaled(self, factor: float) -> CameraIntrinsics:
        """Intrinsics of the image resized by ``factor`` (pixel-centre convention)."""
        w = max(1, int(round(self.width * factor)))
        h = max(1, int(round(self.height * factor)))
        sx, sy = w / self.width, h / self.height
        return CameraIntrinsics(
            fx=self.fx * sx,
            fy=self.fy * sy,
            cx=(self.cx + 0.5) * sx - 0.5,
            cy=(self.cy + 0.5) * sy - 0.5,
            width=w,
            height=h,
            distortion=self.distortion,
        )

    def with_focal(self, scale: float) -> CameraIntrinsics:
        """The same camera with both focal lengths times ``scale`` (itself at 1.0)."""
        if scale == 1.0:
            return self
        return replace(self, fx=self.fx * scale, fy=self.fy * scale)

    def undistorted(self) -> CameraIntrinsics:
        return CameraIntrinsics(self.fx, self.fy, self.cx, self.cy, self.width, self.height, ())


@dataclass
class Frame:
    """One input frame.

    ``image``: [H, W, 3] float32 in [0, 1]; ``depth``: [H, W] float32 metres, NaN = invalid, or None;
    ``T_world_cam_gt``: [4, 4] ground-truth pose when the dataset has one for this timestamp.
    """

    index: int
    timestamp: float
    image: np.ndarray
    intrinsics: CameraIntrinsics
    depth: np.ndarray | None = None
    T_world_cam_gt: np.ndarray | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.image, np.ndarray) or self.image.ndim != 3 or self.image.shape[2] != 3:
            shape = getattr(self.image, "shape", type(self.image).__name__)
            raise TypesError(f"frame {self.index}: image must be a [H, W, 3] numpy array, got {shape}")
        h, w = self.image.shape[:2]
        if (w, h) != (self.intrinsics.width, self.intrinsics.height):
            raise TypesError(
                f"frame {self.index}: image is {w}x{h} but intrinsics say "
                f"{self.intrinsics.width}x{self.intrinsics.height}"
            )
        _check_color(self.image, self.index)
        if self.depth is not None:
            if not isinstance(self.depth, np.ndarray) or self.depth.shape != (h, w):
                shape = getattr(self.depth, "shape", None)
                got = f"{shape[1]}x{shape[0]}" if shape is not None and len(shape) == 2 else str(shape)
                raise TypesError(
                    f"frame {self.index}: depth is {got} but the image is {w}x{h}; "
                    "depth must be a [H, W] array registered to the image"
                )
            _check_depth(self.depth, self.index)
        if self.T_world_cam_gt is not None:
            T = np.asarray(self.T_world_cam_gt)
            if T.shape != (4, 4) or not np.all(np.isfinite(T)):
                raise TypesError(
                    f"frame {self.index}: T_world_cam_gt must be a finite [4, 4] matrix, got "
                    f"{T.shape if T.shape != (4, 4) else 'non-finite values'}; "
                    "pass None when there is no pose"
                )

    @classmethod
    def from_arrays(
        cls,
        index: int,
        timestamp: float,
        image: np.ndarray,
        intrinsics: CameraIntrinsics,
        depth: np.ndarray | None = None,
        T_world_cam_gt: np.ndarray | None = None,
        *,
        depth_scale: float | None = None,
        depth_invalid: float | None = 0,
    ) -> Frame:
        """A frame from arrays in sensor units, converted explicitly to the frame contract.

        ``image``: uint8 (divided by 255), uint16 (divided by 65535) or float already in [0, 1].
        ``depth``: raw sensor values; ``depth_scale`` is the number of raw units per metre (TUM 5000,
        Kinect/7-Scenes millimetres 1000; 1 when the depth is already metres). Raw values equal to
        ``depth_invalid`` (0 by default; None: none) become NaN. Integer depth needs ``depth_scale``.
        """
        img = np.asarray(image)
        if img.dtype == np.uint8:
            img = img.astype(np.float32) / np.float32(255.0)
        elif img.dtype == np.uint16:
            img = img.astype(np.float32) / np.float32(65535.0)
        elif np.issubdtype(img.dtype, np.floating):
            img = img.astype(np.float32, copy=False)
        else:
            raise TypesError(
                f"frame {index}: image dtype {img.dtype} is not supported; "
                "give uint8, uint16 or float in [0, 1]"
            )
        dep = None
        if depth is not None:
            raw = np.asarray(depth)
            if depth_scale is None:
                if not np.issubdtype(raw.dtype, np.floating):
                    raise TypesError(
                        f"frame {index}: depth is {raw.dtype} (raw sensor units); pass depth_scale= "
                        "(raw units per metre: TUM 5000, millimetres 1000)"
                    )
                depth_scale = 1.0
            if not depth_scale > 0:
                raise TypesError(f"frame {index}: depth_scale must be positive, got {depth_scale}")
            dep = raw.astype(np.float32) / np.float32(depth_scale)
            if depth_invalid is not None:
                dep[raw == depth_invalid] = np.nan
        return cls(index, timestamp, np.ascontiguousarray(img), intrinsics, dep, T_world_cam_gt)

    @property
    def gray(self) -> np.ndarray:  # [H, W] float32 in [0, 1]
        return (self.image @ np.array([0.299, 0.587, 0.114], dtype=np.float32)).astype(np.float32)


# A depth map whose median valid value is above this many metres can only be in millimetres (or raw
# sensor units): no RGB-D sensor measures a scene that far, and outdoor stereo medians stay far below.
MAX_MEDIAN_DEPTH_M = 100.0
COLOR_TOLERANCE = 1e-3  # colour values may exceed [0, 1] by this much (resampling round-off)


def _check_color(image: np.ndarray, index: int) -> None:
    """Colour must be float in [0, 1]: uint8 or 0..255 floats are refused with the fix."""
    if not np.issubdtype(image.dtype, np.floating):
        raise TypesError(
            f"frame {index}: image is {image.dtype}; colour must be float in [0, 1]: build the frame with "
            "Frame.from_arrays(...) (converts uint8/uint16) or divide by 255"
        )
    lo, hi = float(image.min()), float(image.max())
    if not (np.isfinite(lo) and np.isfinite(hi)):
        raise TypesError(f"frame {index}: image holds NaN or inf; colour must be finite float in [0, 1]")
    if lo < -COLOR_TOLERANCE or hi > 1.0 + COLOR_TOLERANCE:
        hint = "divide by 255 (or use Frame.from_arrays with the uint8 image)" if hi > 1.5 else "clip it"
        raise TypesError(
            f"frame {index}: image values span {lo:.4g}..{hi:.4g}; colour must be float in [0, 1]: {hint}"
        )


def _check_depth(depth: np.ndarray, index: int) -> None:
    """Depth must be float metres, NaN where invalid; integer or millimetre-sized values are refused."""
    if not np.issubdtype(depth.dtype, np.floating):
        raise TypesError(
            f"frame {index}: depth is {depth.dtype} (raw sensor units?); depth must be float metres with NaN "
            "where invalid: use Frame.from_arrays(..., depth_scale=5000 for TUM, 1000 for millimetres)"
        )
    known = ~np.isnan(depth)
    if not known.any():
        return
    if np.isinf(depth).any() or float(depth.min(where=known, initial=np.inf)) < 0:
        raise TypesError(
            f"frame {index}: depth holds inf or negative values; depth is metres >= 0 with NaN where invalid"
        )
    sample = depth[::4, ::4]
    valid = sample[~np.isnan(sample)]
    median = float(np.median(valid)) if valid.size else float(np.median(depth[known]))
    if median > MAX_MEDIAN_DEPTH_M:
        raise TypesError(
            f"frame {index}: median depth is {median:.4g}, which can only be millimetres or raw units; "
            "depth must be metres: divide by the sensor's scale (1000 for millimetres, 5000 for TUM) or use "
            "Frame.from_arrays(..., depth_scale=...)"
        )


@dataclass
class Trajectory:
    """A timed sequence of poses ``T_world_cam``: timestamps [N] float64 seconds, poses [N, 4, 4]."""

    timestamps: np.ndarray
    poses: np.ndarray
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.timestamps = np.asarray(self.timestamps, dtype=np.float64).reshape(-1)
        self.poses = np.asarray(self.poses, dtype=np.float64)
        if self.poses.ndim != 3 or self.poses.shape[1:] != (4, 4):
            raise TypesError(f"poses must be [N, 4, 4], got {self.poses.shape}")
        if len(self.timestamps) != len(self.poses):
            raise TypesError(
                f"{len(self.timestamps)} timestamps but {len(self.poses)} poses; they must match"
            )

    def __len__(self) -> int:
        return len(self.timestamps)

    @property
    def positions(self) -> np.ndarray:  # [N, 3]
        return self.poses[:, :3, 3]

    def path_length(self) -> float:
        if len(self) < 2:
            return 0.0
        return float(np.linalg.norm(np.diff(self.positions, axis=0), axis=1).sum())


_POINTS, _CONFIDENCE = PointMapField(), CodedField()  # SubmapEncoding's packable fields


@dataclass
class SubmapEncoding:
    """What a submap encoder produces for K+1 keyframes (SING3R's Sub-Track3R output).

    Frame 0 is the keyframe shared with the previous submap (for the first submap: the first
    keyframe). All arrays are in the submap's own local frame and units (one consistent scale
    inside the submap; for RGB-D the units are metres):

    - ``frame_indices``: [K+1] dataset indices of the keyframes.
    - ``T_local_cam``: [K+1, 4, 4] rigid poses camera -> submap-local; ``T_local_cam[0] = I``.
    - ``points_cam``: [K+1, h, w, 3] per-frame point maps X^self in each camera's own frame
      (NaN where unknown), at the resolution of ``intrinsics``.
    - ``confidence``: [K+1, h, w] in [0, 1] (0 where unknown).
    - ``intrinsics``: intrinsics at the point maps' resolution.

    :meth:`pack` keeps ``points_cam`` as its depths and ``confidence`` as uint8 codes where that is
    exact (:mod:`gsslam.compact`); reading them then builds the same arrays anew each time (so
    write into a copy, never into them; :attr:`depths` stays a view of what is stored).
    """

    frame_indices: list[int]
    T_local_cam: np.ndarray
    points_cam: np.ndarray = _POINTS  # type: ignore[assignment]
    confidence: np.ndarray = _CONFIDENCE  # type: ignore[assignment]
    intrinsics: CameraIntrinsics
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = len(self.frame_indices)
        if self.T_local_cam.shape != (n, 4, 4):
            raise TypesError(f"T_local_cam must be [{n}, 4, 4], got {self.T_local_cam.shape}")
        if self.points_cam.ndim != 4 or self.points_cam.shape[0] != n or self.points_cam.shape[3] != 3:
            raise TypesError(f"points_cam must be [{n}, h, w, 3], got {self.points_cam.shape}")
        if self.confidence.shape != self.points_cam.shape[:3]:
            raise TypesError(f"confidence must be {self.points_cam.shape[:3]}, got {self.confidence.shape}")

    @property
    def depths(self) -> np.ndarray:  # [K+1, h, w] z in local units (NaN unknown)
        return _POINTS.depth(self)  # no copy: the stored Z, or a view of the whole point maps

    def pack(self) -> bool:
        """Keep the point maps and confidences compact where that is exact; True when both are packed."""
        points = _POINTS.pack(self)
        return _CONFIDENCE.pack(self) and points

    @property
    def nbytes(self) -> int:
        """Bytes held by the point maps and confidences as stored."""
        return _POINTS.nbytes(self) + _CONFIDENCE.nbytes(self)


@dataclass
class Correspondences:
    """Pixel matches from a source keyframe to a target keyframe (e.g. from dense flow).

    ``uv_src``, ``uv_tgt``: [N, 2] pixel coordinates in the *full-resolution* images of the two
    frames; ``depth_src``: [N] source depth (z) in the units of the source submap (NaN unknown);
    ``weight``: [N] a-priori weights in [0, 1] (e.g. flow forward-backward consistency).
    """

    src_index: int
    tgt_index: int
    uv_src: np.ndarray
    uv_tgt: np.ndarray
    depth_src: np.ndarray
    weight: np.ndarray

    def __post_init__(self) -> None:
        n = len(self.uv_src)
        for name in ("uv_src", "uv_tgt"):
            if getattr(self, name).shape != (n, 2):
                raise TypesError(f"{name} must be [{n}, 2], got {getattr(self, name).shape}")
        for name in ("depth_src", "weight"):
            if getattr(self, name).shape != (n,):
                raise TypesError(f"{name} must be [{n}], got {getattr(self, name).shape}")

    def __len__(self) -> int:
        return len(self.uv_src)


@dataclass
class ImuSamples:
    """IMU measurements: ``timestamps`` [M] float64 s, ``timestamps_ns`` [M] int64, ``gyro`` [M, 3]
    rad/s, ``accel`` [M, 3] m/s^2 (sensor frame); ``noise``: the continuous-time densities
    ``gyroscope_noise_density`` etc. from ``sensor.yaml`` when present; ``T_body_imu`` [4, 4]."""

    timestamps: np.ndarray
    timestamps_ns: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    noise: dict = field(default_factory=dict)
    T_body_imu: np.ndarray = field(default_factory=lambda: np.eye(4))
    synthesized: bool = False  # made from ground truth (gsslam.datasets.imu_synth), not measured

    def __len__(self) -> int:
        return len(self.timestamps)

    def window(self, t0: float, t1: float) -> "ImuSamples":
        """The samples with ``t0 <= t <= t1`` (same noise and extrinsic)."""
        m = (self.timestamps >= t0) & (self.timestamps <= t1)
        return ImuSamples(
            self.timestamps[m], self.timestamps_ns[m], self.gyro[m], self.accel[m], dict(self.noise), self.T_body_imu,
            self.synthesized,
        )
