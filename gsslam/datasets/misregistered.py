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
holes. :class:`Misregistration` is the parsed form of the ``misregister`` dict of the ``playback``
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
from gsslam.types import CameraIntrinsics

REPORTS = ("colour", "depth")


def _flag(v: Any) -> bool:
    return str(v).lower() in ("true", "1", "yes")


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

    def __post_init__(self) -> None:
        if not np.isfinite(self.baseline_m):
            raise MisregistrationError(f"baseline_m must be finite, got {self.baseline_m}")
        if not (np.isfinite(self.focal_scale) and self.focal_scale > 0):
            raise MisregistrationError(f"focal_scale must be positive, got {self.focal_scale}")
        if self.report not in REPORTS:
            raise MisregistrationError(f"report must be one of {REPORTS}, got {self.report!r}")
        if self.ground_truth not in REPORTS:
            raise MisregistrationError(f"ground_truth must be one of {REPORTS}, got {self.ground_truth!r}")

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None) -> Misregistration | None:
        if d is None:
            return None
        unknown = set(d) - {"baseline_m", "focal_scale", "report", "raycast", "ground_truth"}
        if unknown:
            raise MisregistrationError(
                f"unknown misregister keys {sorted(unknown)}; use baseline_m, focal_scale, report, raycast, "
                "ground_truth"
            )
        conv = {"report": str, "ground_truth": str, "raycast": _flag}
        return cls(**{k: conv.get(k, float)(v) for k, v in d.items()})

    def T_colour_depth(self) -> np.ndarray:  # [4, 4] the depth camera in the colour camera frame
        T = np.eye(4)
        T[0, 3] = self.baseline_m
        return T

    def ground_truth_poses(self, T_world_colour: np.ndarray) -> np.ndarray:  # [..., 4, 4] -> the same
        """The colour camera's true poses as the dataset's ground truth gives them (``ground_truth``)."""
        return T_world_colour @ self.T_colour_depth() if self.ground_truth == "depth" else T_world_colour

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


def misregister_depth(
    depth: np.ndarray,  # [H, W] metres, NaN invalid, registered to the colour camera
    colour: CameraIntrinsics,
    baseline_m: float,
    focal_scale: float,
) -> np.ndarray:  # [H, W] float32 metres in the virtual depth camera's pixel grid, NaN invalid
    """The depth image the virtual depth camera would see (module docstring)."""
    h, w = depth.shape
    if (w, h) != (colour.width, colour.height):
        raise MisregistrationError(f"depth is {w}x{h} but the intrinsics say {colour.width}x{colour.height}")
    vs, us = np.nonzero(np.isfinite(depth) & (depth > 0))
    z = depth[vs, us].astype(np.float64)
    x = (us - colour.cx) / colour.fx * z - baseline_m  # in the depth camera's frame
    y = (vs - colour.cy) / colour.fy * z
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
