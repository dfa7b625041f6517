"""Ray-cast scenes: textured surfaces intersected exactly by every pixel ray (numpy).

A ``Scene`` is a list of surfaces; ``Scene.cast(T_world_cam, intrinsics)`` returns the image
[H, W, 3] and the exact z-depth [H, W] (NaN where no surface is hit). Pixel rays have unit
camera z, so the ray parameter of the first hit is the depth. Surfaces (world frame, y down):

- ``Box``: the inside of an axis-aligned box centred on the origin (a room); six textures in face
  order ``2 * axis + (positive side)`` (-x, +x, -y, +y, -z, +z) and a brightness per face.
  Surface coordinates of a face are the two other axes (ascending), offset by the half extent.
- ``Rectangle``: a finite plane patch ``origin + u axis_u + v axis_v``, u in [0, extent_u).
- ``Sphere``: seen from outside; coordinates (longitude, latitude) in [0, 1], lit from above.
- ``Cylinder``: the inside of an infinite vertical (y) cylinder around the origin; coordinates
  (arc length, y).

A new surface needs ``hit(o, d) -> (t [N], part [N] int)`` (``inf`` where missed, only t > 0)
and ``colour(points [M, 3], part [M]) -> [M, 3]``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from gsslam.datasets.base import DatasetError
from gsslam.types import CameraIntrinsics

_EPS = 1e-9


class SceneError(DatasetError):
    """A synthetic scene cannot be rendered as asked (e.g. the camera left the room)."""


class Texture(Protocol):
    def sample(self, u: np.ndarray, v: np.ndarray) -> np.ndarray: ...  # u, v [N] -> [N, 3]


class Surface(Protocol):
    def hit(self, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...

    def colour(self, points: np.ndarray, part: np.ndarray) -> np.ndarray: ...


@dataclass
class Box:
    half_extent: np.ndarray  # [3] (x, y, z) metres
    textures: list[Texture]  # 6, face order -x, +x, -y, +y, -z, +z
    brightness: np.ndarray = field(default_factory=lambda: np.ones(6, np.float32))  # [6]

    def hit(self, o, d):  # o [3], d [N, 3] -> t [N], face [N]
        he = np.asarray(self.half_extent, np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            t_hi = (he - o) / d
            t_lo = (-he - o) / d
        t_axes = np.where(d > 0, t_hi, t_lo)
        t_axes = np.where(np.abs(d) < 1e-12, np.inf, t_axes)
        axis = np.argmin(t_axes, axis=1)
        t = t_axes[np.arange(len(d)), axis]
        face = 2 * axis + (np.take_along_axis(d, axis[:, None], 1)[:, 0] > 0)
        return np.where(t > _EPS, t, np.inf), face

    def colour(self, points, part):  # points [M, 3], face [M] -> [M, 3]
        out = np.zeros((len(points), 3), np.float32)
        for f in np.unique(part):
            m = part == f
            a, b = [ax for ax in range(3) if ax != f // 2]
            uv = points[m][:, [a, b]] + self.half_extent[[a, b]]
            out[m] = self.brightness[f] * self.textures[f].sample(uv[:, 0], uv[:, 1])
        return out

    def contains(self, p: np.ndarray) -> bool:
        return bool(np.all(np.abs(p) < self.half_extent))


@dataclass
class Rectangle:
    origin: np.ndarray  # [3] a corner
    axis_u: np.ndarray  # [3] unit
    axis_v: np.ndarray  # [3] unit, orthogonal to axis_u
    extent: tuple[float, float]  # metres along u, v
    texture: Texture

    def hit(self, o, d):
        n = np.cross(self.axis_u, self.axis_v)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((self.origin - o) @ n) / (d @ n)
        X = o + t[:, None] * d
        a = (X - self.origin) @ self.axis_u / self.extent[0]
        b = (X - self.origin) @ self.axis_v / self.extent[1]
        ok = (t > 1e-6) & (a >= 0) & (a < 1) & (b >= 0) & (b < 1)
        return np.where(ok, t, np.inf), np.zeros(len(d), int)

    def colour(self, points, part):
        rel = points - self.origin
        return self.texture.sample(rel @ self.axis_u, rel @ self.axis_v)


@dataclass
class Sphere:
    centre: np.ndarray  # [3]
    radius: float
    texture: Texture  # over (longitude, latitude) in [0, 1]

    def hit(self, o, d):
        oc = o - self.centre
        b = d @ oc
        a2 = (d * d).sum(1)
        disc = b * b - a2 * (oc @ oc - self.radius**2)
        t = np.full(len(d), np.inf)
        h = disc > 0
        t[h] = (-b[h] - np.sqrt(disc[h])) / a2[h]
        return np.where(t > _EPS, t, np.inf), np.zeros(len(d), int)

    def colour(self, points, part):
        n = (points - self.centre) / self.radius
        lon = (np.arctan2(n[:, 0], n[:, 2]) + np.pi) / (2 * np.pi)
        lat = np.arccos(np.clip(n[:, 1], -1, 1)) / np.pi
        shade = 0.7 + 0.3 * np.clip(-n[:, 1], 0, 1)  # fixed "light from above": view-independent
        return shade[:, None].astype(np.float32) * self.texture.sample(lon, lat)


@dataclass
class Cylinder:
    radius: float
    texture: Texture  # over (arc length, y)

    def hit(self, o, d):
        a = d[:, 0] ** 2 + d[:, 2] ** 2
        b = 2 * (o[0] * d[:, 0] + o[2] * d[:, 2])
        c = o[0] ** 2 + o[2] ** 2 - self.radius**2
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (-b + np.sqrt(b * b - 4 * a * c)) / (2 * a)  # the far root: seen from inside
        return np.where(np.isfinite(t) & (t > _EPS), t, np.inf), np.zeros(len(d), int)

    def colour(self, points, part):
        arc = (np.arctan2(points[:, 2], points[:, 0]) + np.pi) * self.radius
        return self.texture.sample(arc, points[:, 1])


def pixel_rays(intr: CameraIntrinsics) -> np.ndarray:  # -> [H*W, 3] camera rays with z = 1
    u, v = np.meshgrid(np.arange(intr.width, dtype=np.float64), np.arange(intr.height, dtype=np.float64))
    return np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones_like(u)], -1).reshape(-1, 3)


@dataclass
class Scene:
    """Surfaces rendered together; ``room`` (optional) is the box the camera must stay inside."""

    surfaces: list[Surface]
    room: Box | None = None
    _rays: dict = field(default_factory=dict, repr=False)

    def rays(self, intr: CameraIntrinsics) -> np.ndarray:  # -> [H*W, 3], cached per camera
        key = (intr.fx, intr.fy, intr.cx, intr.cy, intr.width, intr.height)
        if key not in self._rays:
            self._rays[key] = pixel_rays(intr)
        return self._rays[key]

    def cast(
        self,
        T_world_cam: np.ndarray,
        intr: CameraIntrinsics,  # [4, 4]
    ) -> tuple[np.ndarray, np.ndarray]:  # image [H, W, 3] float32, depth [H, W] float64 (NaN: no hit)
        R, o = T_world_cam[:3, :3], np.asarray(T_world_cam[:3, 3], np.float64)
        if self.room is not None and not self.room.contains(o):
            raise SceneError(f"camera at {o} is outside the room {self.room.half_extent}")
        d = self.rays(intr) @ R.T  # [N, 3] world directions with unit camera z
        best = np.full(len(d), np.inf)
        which = np.full(len(d), -1)
        parts = []
        for k, s in enumerate(self.surfaces):
            t, part = s.hit(o, d)
            closer = t < best
            best[closer], which[closer] = t[closer], k
            parts.append(part)
        image = np.zeros((len(d), 3), np.float32)
        for k, s in enumerate(self.surfaces):
            m = which == k
            if m.any():
                image[m] = s.colour(o + best[m, None] * d[m], parts[k][m])
        depth = np.where(np.isfinite(best), best, np.nan)
        h, w = intr.height, intr.width
        return np.clip(image, 0, 1).reshape(h, w, 3), depth.reshape(h, w)

    def points(self, T_world_cam: np.ndarray, intr: CameraIntrinsics) -> np.ndarray:  # -> [H, W, 3]
        """Camera-frame points of the first hits (NaN where none)."""
        _, depth = self.cast(T_world_cam, intr)
        return self.rays(intr).reshape(intr.height, intr.width, 3) * depth[..., None]
