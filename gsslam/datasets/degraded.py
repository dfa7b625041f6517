"""Simulated hand-held capture: motion blur along the ground-truth motion and auto-exposure swings.

A quick hand moves the camera during the exposure, and a Kinect v1's auto-exposure brightens and
darkens the image as it turns towards light or dark parts of a room. Both are synthesized here from
what a played-back sequence knows exactly (:mod:`gsslam.datasets.playback`): the ground-truth poses of
the played frames and the (registered) sensor depth of each source frame.

- **Motion blur** (``shutter > 0``): the exposure of played frame ``k`` spans ``shutter`` played-frame
  periods centred on it. Its two ends are ground-truth poses (geodesic interpolation towards frame
  ``k - 1`` for the start and ``k + 1`` for the end, so a paused camera has no blur and a faster
  playback, ``stride > 1``, more of it). Each pixel's 3D point (the depth, holes filled with the median
  depth) is projected into both end cameras: its pixel motion. ``blur_samples`` views along the
  exposure move linearly in time along it; the view there is, to first order in the motion, frame ``k``
  resampled at ``uv - flow(uv)``; the blurred image is their mean.
- **Exposure** (``exposure_amp > 0``): frame ``k``'s colour is multiplied by
  ``exp(exposure_amp * sin(2 pi k / exposure_period + phase))`` and clipped to [0, 1] (saturation);
  the phase is 0 for ``seed=0`` and drawn from ``seed`` otherwise.

:class:`Degradation` is the parsed form of the ``degrade`` dict of the ``playback`` dataset. Everything
is a deterministic function of the frame index, the poses and ``seed``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from gsslam.datasets.base import DatasetError
from gsslam.geometry import interpolate_pose, invert_T
from gsslam.types import CameraIntrinsics

FLOW_STEP = 4  # px: the grid the pixel motion is computed on (then resized to the image)
KEYS = ("shutter", "blur_samples", "exposure_amp", "exposure_period", "seed")


class DegradationError(DatasetError):
    """A degradation setting is malformed, or blur is asked of a sequence without depth."""


@dataclass(frozen=True)
class Degradation:
    """What is done to each played frame (see the module docstring)."""

    shutter: float = 0.0  # exposure time in played-frame periods; 0: no motion blur
    blur_samples: int = 9  # camera poses averaged along the exposure
    exposure_amp: float = 0.0  # log-gain amplitude of the exposure swing; 0: none
    exposure_period: float = 90.0  # played frames per exposure swing
    seed: int = 0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.shutter) and 0.0 <= self.shutter <= 2.0):
            raise DegradationError(f"shutter must be in [0, 2] frame periods, got {self.shutter}")
        if self.blur_samples < 2:
            raise DegradationError(f"blur_samples must be >= 2, got {self.blur_samples}")
        if not (np.isfinite(self.exposure_amp) and 0.0 <= self.exposure_amp <= 2.0):
            raise DegradationError(f"exposure_amp must be in [0, 2], got {self.exposure_amp}")
        if not (np.isfinite(self.exposure_period) and self.exposure_period > 0):
            raise DegradationError(f"exposure_period must be positive, got {self.exposure_period}")

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None) -> Degradation | None:
        if d is None:
            return None
        unknown = set(d) - set(KEYS)
        if unknown:
            raise DegradationError(f"unknown degrade keys {sorted(unknown)}; use {', '.join(KEYS)}")
        ints = ("blur_samples", "seed")
        return cls(**{k: (int(v) if k in ints else float(v)) for k, v in d.items()})

    @property
    def blurs(self) -> bool:
        return self.shutter > 0.0

    def gain(self, k: int) -> float:
        """Exposure gain of played frame ``k``."""
        if self.exposure_amp == 0.0:
            return 1.0
        phase = 0.0 if self.seed == 0 else float(np.random.default_rng(self.seed).uniform(0.0, 2 * np.pi))
        return float(np.exp(self.exposure_amp * np.sin(2 * np.pi * k / self.exposure_period + phase)))


def exposure_ends(
    deg: Degradation,
    T_prev: np.ndarray | None,  # [4, 4] T_world_cam of played frame k - 1 (None: unknown / first)
    T_k: np.ndarray,  # [4, 4] T_world_cam of played frame k
    T_next: np.ndarray | None,  # [4, 4] of played frame k + 1
) -> tuple[np.ndarray, np.ndarray]:  # [4, 4] x2: T_cam_u_cam_k at the start and at the end of the exposure
    """The cameras at both ends of frame ``k``'s exposure, relative to frame ``k`` (identity when the
    neighbour's pose is unknown)."""
    ends = []
    for other in (T_prev, T_next):
        T_u = T_k if other is None else interpolate_pose(T_k, other, 0.5 * deg.shutter)
        ends.append(invert_T(T_u) @ T_k)
    return ends[0], ends[1]


def _flow(X: tuple, T: np.ndarray, intr: CameraIntrinsics, u: np.ndarray, v: np.ndarray):
    """Pixel motion [H, W] x2 of the points X (x, y, z planes [H, W] of frame k) seen from camera ``T``."""
    R, t = T[:3, :3].astype(np.float32), T[:3, 3].astype(np.float32)
    x, y, z = (R[r, 0] * X[0] + R[r, 1] * X[1] + R[r, 2] * X[2] + t[r] for r in range(3))
    z = np.maximum(z, np.float32(1e-3))
    fx, fy, cx, cy = (np.float32(a) for a in (intr.fx, intr.fy, intr.cx, intr.cy))
    return fx * x / z + cx - u, fy * y / z + cy - v


def motion_blur(
    image: np.ndarray,  # [H, W, 3] float in [0, 1]
    depth: np.ndarray,  # [H, W] metres, NaN / 0 invalid, registered to the image
    intr: CameraIntrinsics,
    ends: tuple[np.ndarray, np.ndarray],  # T_cam_u_cam_k at the start and the end of the exposure
    samples: int = 9,
) -> np.ndarray:  # [H, W, 3] float32: the mean of the sample views
    """The image integrated over the exposure (module docstring). The pixel motion is computed exactly
    at both ends; the ``samples`` views between them move along it linearly in time (first order, as
    the resampling itself)."""
    h, w = depth.shape
    d = depth[::FLOW_STEP, ::FLOW_STEP]  # the motion is smooth: computed on a coarse grid, then resized
    ok = np.isfinite(d) & (d > 0)
    if not ok.any():
        raise DegradationError("motion blur needs depth; this frame has no valid depth pixel")
    z = np.where(ok, d, np.float32(np.median(d[ok]))).astype(np.float32)
    cu, cv = np.meshgrid(
        np.arange(0, w, FLOW_STEP, dtype=np.float32), np.arange(0, h, FLOW_STEP, dtype=np.float32)
    )
    fx, fy, cx, cy = (np.float32(a) for a in (intr.fx, intr.fy, intr.cx, intr.cy))
    X = ((cu - cx) / fx * z, (cv - cy) / fy * z, z)
    flows = [
        [cv2.resize(f, (w, h), interpolation=cv2.INTER_LINEAR) for f in _flow(X, T, intr, cu, cv)]
        for T in ends
    ]
    u, v = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    img = np.ascontiguousarray(image, dtype=np.float32)
    acc = np.zeros_like(img)
    for s in np.linspace(-1.0, 1.0, samples):
        du, dv = flows[0] if s < 0 else flows[1]
        a = np.float32(abs(s))
        acc += cv2.remap(img, u - a * du, v - a * dv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return acc / samples


def apply_exposure(image: np.ndarray, gain: float) -> np.ndarray:  # [H, W, 3] -> [H, W, 3] float32
    if gain == 1.0:
        return image
    return np.clip(image.astype(np.float32) * np.float32(gain), 0.0, 1.0)
