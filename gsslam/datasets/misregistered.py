"""Simulated unregistered depth: what a Kinect v1 hands out when depth is not registered to colour.

A Kinect v1 has two cameras: the colour camera and the infrared depth camera, ~2.5 cm apart along x,
with different focal lengths (colour ~525 px, depth ~585 px at 640x480). Datasets such as
Microsoft 7-Scenes ship the depth image *in the depth camera's pixel grid* at the colour image's size,
so the depth at colour pixel ``(u, v)`` belongs to a different scene point than the colour there.

:func:`misregister_depth` turns a registered depth map (TUM's, in the colour camera) into such an
image: every valid pixel is back-projected with the colour intrinsics, moved into a virtual depth
camera at ``T_depth_colour`` (a translation of ``-baseline_m`` along x: the depth camera sits
``baseline_m`` to the right of the colour camera) with focal lengths ``focal_scale * (fx, fy)`` and
the same principal point, and splatted there with a z-buffer (nearest surface wins, each point fills
the up-to-4 pixels around its projection so that a magnified image has no cracks).

The splat's nearest-wins rule biases a slanted surface towards the camera (-2.2 mm mean, 3.2 mm RMS on a
plane at 1.5-3 m, 320x240); a synthetic scene can ray-cast the depth camera instead (``raycast: true``,
session 13). ``focal_scale > 1``: the depth camera sees a narrower field of view than the colour camera (the
Kinect v1 case, 585 / 525 ~ 1.114), every depth pixel has a scene point; ``< 1`` leaves a border of
holes.

A real Kinect v1's depth camera is also rotated against its colour camera (~0.45 deg about x and y, 0.16 deg
about z in the LIRIS calibration 7-Scenes users apply) and offset off the x axis (~2 mm along z):
``rotation_deg = [rx, ry, rz]`` is the depth camera's orientation in the colour camera frame as a rotation
vector in degrees (``R_colour_depth = exp(rx, ry, rz)``: a colour-frame direction ``d`` is ``R^T d`` in the
depth frame), and ``offset_m = [ty, tz]`` the rest of its centre: ``t_colour_depth = (baseline_m, ty, tz)``.
A colour-frame point ``X`` is ``R^T (X - t)`` in the depth camera. So ``ry > 0`` turns the depth camera's
optical axis towards +x (a point straight ahead appears at ``u < cx`` in the depth image) and ``rx > 0`` turns
it towards -y (the point appears at ``v > cy``). Both default to zero: the images are then the same to the
byte as without them (session 16).

:class:`Misregistration` is the parsed form of the ``misregister`` dict of the ``playback``
dataset; its ``report`` says which intrinsics the dataset hands out with the frames: ``"colour"``
(the truth for the colour image) or ``"depth"`` (the depth camera's, as the 7-Scenes loader does with
fx = fy = 585 for colour too); its ``ground_truth`` says which camera the dataset's ground truth poses:
``"colour"`` or ``"depth"`` (7-Scenes' ``pose.txt`` are the depth camera's, ``T_world_colour @
T_colour_depth``; :mod:`gsslam.run.trajectory_camera`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from gsslam.datasets.base import DatasetError
from gsslam.geometry import so3_exp
from gsslam.types import CameraIntrinsics

REPORTS = ("colour", "depth")


def _flag(v: Any) -> bool:
    return str(v).lower() in ("true", "1", "yes")


def _floats(v: Any) -> tuple[float, ...]:
    return tuple(float(x) for x in v)


class MisregistrationError(DatasetError):
    """A misregistration setting is malformed."""


@dataclass(frozen=True)
class Misregistration:
    """A virtual depth camera relative to the colour camera (see the module docstring)."""

    baseline_m: float = 0.025
    focal_scale: float = 1.0
    report: str = "colour"
    raycast: bool = False  # synthetic scenes only: ray-cast the depth camera instead of re-projecting
    ground_truth: str = "colour"  # the camera the ground truth poses: "colour" or "depth" (7-Scenes)
    rotation_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)  # R_colour_depth's rotation vector (doc)
    offset_m: tuple[float, float] = (0.0, 0.0)  # (y, z) of the depth camera's centre in the colour frame

    def __post_init__(self) -> None:
        if not np.isfinite(self.baseline_m):
            raise MisregistrationError(f"baseline_m must be finite, got {self.baseline_m}")
        if not (np.isfinite(self.focal_scale) and self.focal_scale > 0):
            raise MisregistrationError(f"focal_scale must be positive, got {self.focal_scale}")
        if self.report not in REPORTS:
            raise MisregistrationError(f"report must be one of {REPORTS}, got {self.report!r}")
        if self.ground_truth not in REPORTS:
            raise MisregistrationError(f"ground_truth must be one of {REPORTS}, got {self.ground_truth!r}")
        for name, n, bound in (("rotation_deg", 3, 10.0), ("offset_m", 2, 0.2)):
            v = np.asarray(getattr(self, name), dtype=np.float64)
            if v.shape != (n,) or not np.all(np.isfinite(v)) or np.any(np.abs(v) > bound):
                raise MisregistrationError(
                    f"{name} must be {n} finite numbers within +-{bound}, got {getattr(self, name)}"
                )

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None) -> Misregistration | None:
        if d is None:
            return None
        keys = ("baseline_m", "focal_scale", "report", "raycast", "rotation_deg", "offset_m", "ground_truth")
        unknown = set(d) - set(keys)
        if unknown:
            raise MisregistrationError(f"unknown misregister keys {sorted(unknown)}; use {', '.join(keys)}")
        conv = {
            "report": str, "ground_truth": str, "raycast": _flag, "rotation_deg": _floats, "offset_m": _floats,
        }  # fmt: skip
        return cls(**{k: conv.get(k, float)(v) for k, v in d.items()})

    def T_colour_depth(self) -> np.ndarray:  # [4, 4] the depth camera's pose in the colour camera frame
        return depth_camera_pose(self.baseline_m, self.rotation_deg, self.offset_m)

    def ground_truth_poses(self, T_world_colour: np.ndarray) -> np.ndarray:  # [..., 4, 4] -> the same
        """The colour camera's true poses as the dataset's ground truth gives them (``ground_truth``)."""
        return T_world_colour @ self.T_colour_depth() if self.ground_truth == "depth" else T_world_colour

    def is_along_x(self) -> bool:
        """No rotation and no offset: the depth camera only shifted along x (the model before session 16)."""
        return not any(self.rotation_deg) and not any(self.offset_m)

    def depth_intrinsics(self, colour: CameraIntrinsics) -> CameraIntrinsics:
        return CameraIntrinsics(
            colour.fx * self.focal_scale,
            colour.fy * self.focal_scale,
            colour.cx,
            colour.cy,
            colour.width,
            colour.height,
        )

    def reported_intrinsics(self, colour: CameraIntrinsics) -> CameraIntrinsics:
        return colour if self.report == "colour" else self.depth_intrinsics(colour)


def depth_camera_pose(
    baseline_m: float, rotation_deg=(0.0, 0.0, 0.0), offset_m=(0.0, 0.0)
) -> np.ndarray:  # [4, 4] T_colour_depth (module docstring)
    T = np.eye(4)
    if any(rotation_deg):
        T[:3, :3] = so3_exp(np.radians(np.asarray(rotation_deg, dtype=np.float64)))
    T[:3, 3] = (baseline_m, *offset_m)
    return T


def misregister_depth(
    depth: np.ndarray,  # [H, W] metres, NaN invalid, registered to the colour camera
    colour: CameraIntrinsics,
    baseline_m: float,
    focal_scale: float,
    rotation_deg=(0.0, 0.0, 0.0),  # R_colour_depth's rotation vector, degrees (module docstring)
    offset_m=(0.0, 0.0),  # (y, z) of the depth camera's centre in the colour frame
) -> np.ndarray:  # [H, W] float32 metres in the virtual depth camera's pixel grid, NaN invalid
    """The depth image the virtual depth camera would see (module docstring)."""
    h, w = depth.shape
    if (w, h) != (colour.width, colour.height):
        raise MisregistrationError(f"depth is {w}x{h} but the intrinsics say {colour.width}x{colour.height}")
    vs, us = np.nonzero(np.isfinite(depth) & (depth > 0))
    z = depth[vs, us].astype(np.float64)
    x = (us - colour.cx) / colour.fx * z - baseline_m  # in the depth camera's frame
    y = (vs - colour.cy) / colour.fy * z
    if any(rotation_deg) or any(offset_m):  # X_depth = R^T (X_colour - t); along x alone the lines above
        T = depth_camera_pose(baseline_m, rotation_deg, offset_m)
        X = np.stack([x, y - T[1, 3], z - T[2, 3]], 1) @ T[:3, :3]  # rows: (R^T (X - t))^T
        x, y, z = X[:, 0], X[:, 1], X[:, 2]
        front = z > 1e-6
        x, y, z = x[front], y[front], z[front]
    u = np.round(colour.cx + colour.fx * focal_scale * x / z, 6)  # round: exact integers stay exact
    v = np.round(colour.cy + colour.fy * focal_scale * y / z, 6)
    out = np.full(h * w, np.inf)
    cols = [np.floor(u), np.ceil(u)]
    rows = [np.floor(v), np.ceil(v)]
    idx_all, z_all = [], []
    for uu in cols:
        for vv in rows:
            ok = (uu >= 0) & (uu < w) & (vv >= 0) & (vv < h)
            idx_all.append((vv[ok] * w + uu[ok]).astype(np.int64))
            z_all.append(z[ok])
    idx = np.concatenate(idx_all)
    zz = np.concatenate(z_all)
    np.minimum.at(out, idx, zz)
    out[~np.isfinite(out)] = np.nan
    return out.reshape(h, w).astype(np.float32)
