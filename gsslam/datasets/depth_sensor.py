"""A Kinect v1 structured-light depth sensor applied to exact depth: noise, quantization and holes.

The synthetic scenes give exact depth; a Kinect v1 hands out something else. :func:`kinect_v1_depth`
turns an exact depth image (in the depth camera's pixel grid) into what the sensor gives, a
deterministic function of the image and a ``numpy.random.Generator``:

- **Random error growing with z^2**: ``z + N(0, (sigma_z2 * z^2)^2)``, ``sigma_z2 = 1.43e-3 /m``
  (Khoshelham & Oude Elberink, "Accuracy and resolution of Kinect depth data for indoor mapping
  applications", Sensors 12(2):1437-1454, 2012: theoretical random error ``1.425e-3 Z^2`` for a
  disparity std of 1/2 px, and measured ~1.5 mm at 1 m to ~4 cm at 5 m). Pixels are independent
  (the real sensor's 9x9 correlation window is not modelled).
- **Disparity quantization**: the sensor measures disparity in 1/8 px; depth is ``K / d`` with ``d``
  an integer in those units and ``K = 8 f b`` (f = 580 px at 640x480, b = 7.5 cm projector-camera
  baseline -> ``K = 348 m``), so the depth step is ``z^2 / K`` (2.9 mm at 1 m, 4.6 cm at 4 m, 7.2 cm
  at 5 m, as the paper measures). Physical, independent of the image size handed out.
- **Holes** (NaN): beyond ``max_range_m`` (4 m) and nearer than ``min_range_m`` (0.5 m); at grazing
  incidence (the angle between the pixel ray and the surface normal, from the depth's own point map,
  above ``max_incidence_deg``); in a band of ``edge_band_px`` pixels on both sides of every depth
  discontinuity (neighbouring depths differing by more than ``edge_jump`` relative: the IR shadow and
  the correlation window's mixed pixels); and ``dropout`` of the remaining pixels at random.

:class:`KinectV1` is the parsed form of the ``sensor`` dict of the ``synthetic`` dataset (``"kinect_v1"``
gives the defaults).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

import cv2
import numpy as np

from gsslam.datasets.base import DatasetError
from gsslam.types import CameraIntrinsics


class DepthSensorError(DatasetError):
    """A depth-sensor setting is malformed."""


@dataclass(frozen=True)
class KinectV1:
    """The sensor's parameters (module docstring); 0 switches a term off."""

    sigma_z2: float = 1.43e-3  # 1/m: random error std = sigma_z2 * z^2
    disparity_k: float = 348.0  # m: 8 (sub-pixel) * 580 px * 0.075 m; 0: no quantization
    min_range_m: float = 0.5
    max_range_m: float = 4.0  # 0: no far cut
    max_incidence_deg: float = 75.0  # 90: no grazing holes
    edge_band_px: int = 2  # 0: no band at depth edges
    edge_jump: float = 0.05  # relative depth step between neighbours that makes an edge
    dropout: float = 0.0  # fraction of the remaining pixels dropped at random

    def __post_init__(self) -> None:
        checks = {
            "sigma_z2": 0.0 <= self.sigma_z2 < 0.1,
            "disparity_k": self.disparity_k == 0.0 or self.disparity_k > 1.0,
            "min_range_m": 0.0 <= self.min_range_m < 10.0,
            "max_range_m": self.max_range_m == 0.0 or self.max_range_m > self.min_range_m,
            "max_incidence_deg": 0.0 < self.max_incidence_deg <= 90.0,
            "edge_band_px": 0 <= self.edge_band_px <= 32,
            "edge_jump": 0.0 < self.edge_jump < 10.0,
            "dropout": 0.0 <= self.dropout < 1.0,
        }
        for name, ok in checks.items():
            value = getattr(self, name)
            if not (ok and np.isfinite(value)):
                raise DepthSensorError(f"sensor.{name} is out of range: {value}")

    @classmethod
    def from_spec(cls, spec: str | dict[str, Any] | KinectV1 | None) -> KinectV1 | None:
        """``None`` (exact depth), ``"kinect_v1"`` (the defaults) or a dict of overrides."""
        if spec is None or isinstance(spec, KinectV1):
            return spec
        if spec == "kinect_v1":
            return cls()
        if not isinstance(spec, dict):
            raise DepthSensorError(f"sensor must be 'kinect_v1' or a dict of its parameters, got {spec!r}")
        names = {f.name for f in fields(cls)}
        d = {k: v for k, v in spec.items() if k != "model"}
        if spec.get("model", "kinect_v1") != "kinect_v1":
            raise DepthSensorError(f"sensor.model must be 'kinect_v1', got {spec.get('model')!r}")
        unknown = set(d) - names
        if unknown:
            raise DepthSensorError(f"unknown sensor keys {sorted(unknown)}; use model, {', '.join(sorted(names))}")
        return cls(**{k: (int(v) if k == "edge_band_px" else float(v)) for k, v in d.items()})


def incidence_cos(depth: np.ndarray, intr: CameraIntrinsics) -> np.ndarray:  # [H, W] -> [H, W]
    """|cos| of the angle between each pixel's ray and the surface normal of the depth's point map
    (central differences; NaN where a neighbour is missing)."""
    h, w = depth.shape
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    z = depth.astype(np.float64)
    P = np.stack([(u - intr.cx) / intr.fx * z, (v - intr.cy) / intr.fy * z, z], -1)  # [H, W, 3]
    du = np.full_like(P, np.nan)
    dv = np.full_like(P, np.nan)
    du[:, 1:-1] = P[:, 2:] - P[:, :-2]
    dv[1:-1] = P[2:] - P[:-2]
    n = np.cross(du, dv)
    ray = np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones_like(u)], -1)
    with np.errstate(invalid="ignore", divide="ignore"):
        c = np.abs((n * ray).sum(-1)) / (np.linalg.norm(n, axis=-1) * np.linalg.norm(ray, axis=-1))
    return c


def edge_mask(depth: np.ndarray, jump: float, band_px: int) -> np.ndarray:  # [H, W] -> [H, W] bool
    """Pixels within ``band_px`` of a discontinuity: a 4-neighbour whose depth differs by more than
    ``jump`` times the nearer one, or a valid pixel beside a missing one (a silhouette on nothing)."""
    z = np.where(np.isfinite(depth) & (depth > 0), depth, np.inf).astype(np.float64)
    edge = np.zeros(depth.shape, bool)
    for a, b in (((slice(None), slice(1, None)), (slice(None), slice(None, -1))),
                 ((slice(1, None), slice(None)), (slice(None, -1), slice(None)))):
        za, zb = z[a], z[b]
        near = np.minimum(za, zb)
        with np.errstate(invalid="ignore"):
            step = np.abs(za - zb) > jump * near
        step &= np.isfinite(near)
        edge[a] |= step
        edge[b] |= step
    if band_px > 1:
        k = np.ones((2 * (band_px - 1) + 1,) * 2, np.uint8)
        edge = cv2.dilate(edge.astype(np.uint8), k) > 0
    return edge


def kinect_v1_depth(
    depth: np.ndarray,  # [H, W] exact metres in the depth camera's grid, NaN / 0 invalid
    intr: CameraIntrinsics,  # the depth camera's intrinsics (normals for the grazing holes)
    sensor: KinectV1,
    rng: np.random.Generator,
) -> np.ndarray:  # [H, W] float32 metres, NaN where the sensor gives nothing
    """What the sensor hands out for ``depth`` (module docstring)."""
    z = depth.astype(np.float64)
    valid = np.isfinite(z) & (z > 0)
    hole = ~valid | (z < sensor.min_range_m)
    if sensor.max_range_m > 0:
        hole |= z > sensor.max_range_m
    if sensor.max_incidence_deg < 90.0:
        c = incidence_cos(np.where(valid, z, np.nan), intr)
        hole |= np.isfinite(c) & (c < np.cos(np.deg2rad(sensor.max_incidence_deg)))
    if sensor.edge_band_px > 0:
        hole |= edge_mask(z, sensor.edge_jump, sensor.edge_band_px)
    noise = rng.standard_normal(z.shape)  # drawn for every pixel: the same draws whatever the holes
    drop = rng.random(z.shape) < sensor.dropout if sensor.dropout > 0 else np.zeros(z.shape, bool)
    out = np.where(hole, np.nan, z)
    out = out + sensor.sigma_z2 * out * out * noise
    if sensor.disparity_k > 0:
        with np.errstate(invalid="ignore", divide="ignore"):
            d = np.round(sensor.disparity_k / out)
            out = np.where(d >= 1, sensor.disparity_k / d, np.nan)
    out[drop | ~np.isfinite(out) | (out <= 0)] = np.nan
    return out.astype(np.float32)
