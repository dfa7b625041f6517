"""A small ray-cast scene with exact depth and poses for the monocular encoder tests.

A box room (back wall, floor, left wall) plus a floating cube face, each plane carrying a
band-limited random texture; frames are rendered by exact ray-plane intersection, so the depth
of every pixel and every camera pose are known exactly.
"""

from __future__ import annotations

import cv2
import numpy as np

from gsslam.geometry import make_T, so3_exp
from gsslam.types import CameraIntrinsics, Frame

INTR = CameraIntrinsics(fx=260.0, fy=260.0, cx=159.5, cy=119.5, width=320, height=240)


def _texture(rng: np.random.Generator, size: int = 512) -> np.ndarray:  # [size, size, 3] in [0, 1]
    t = np.zeros((size, size, 3), np.float32)
    for octave, amp in ((8, 0.5), (32, 0.3), (128, 0.2)):
        small = rng.random((octave, octave, 3)).astype(np.float32)
        t += amp * cv2.resize(small, (size, size), interpolation=cv2.INTER_CUBIC)
    return np.clip(t, 0, 1)


class PlaneScene:
    """Planes ``n . X = d`` (world frame), each with an origin, two in-plane axes and a texture."""

    def __init__(self, seed: int = 0) -> None:
        rng = np.random.default_rng(seed)
        # (point on plane, axis u, axis v, extent u, extent v)
        self.planes = [
            (
                np.array([-2.0, -1.5, 4.0]),
                np.array([1.0, 0, 0]),
                np.array([0, 1.0, 0]),
                4.0,
                3.0,
            ),  # back wall
            (
                np.array([-2.0, 1.0, 0.5]),
                np.array([1.0, 0, 0]),
                np.array([0, 0, 1.0]),
                4.0,
                3.5,
            ),  # floor (y down)
            (
                np.array([-1.6, -1.5, 0.5]),
                np.array([0, 0, 1.0]),
                np.array([0, 1.0, 0]),
                3.5,
                2.5,
            ),  # left wall
            (
                np.array([0.1, -0.2, 2.5]),
                np.array([1.0, 0, 0.3]) / np.hypot(1, 0.3),
                np.array([0, 1.0, 0]),
                0.7,
                0.7,
            ),
        ]
        self.textures = [_texture(rng) for _ in self.planes]

    def render(self, T_world_cam: np.ndarray, intr: CameraIntrinsics = INTR) -> tuple[np.ndarray, np.ndarray]:
        """-> image [H, W, 3] float32, depth [H, W] float32 (z, NaN where no plane is hit)."""
        H, W = intr.height, intr.width
        u, v = np.meshgrid(np.arange(W), np.arange(H))
        d_cam = np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones_like(u, float)], -1)
        R, c = T_world_cam[:3, :3], T_world_cam[:3, 3]
        d = d_cam.reshape(-1, 3) @ R.T
        best_t = np.full(H * W, np.inf)
        img = np.zeros((H * W, 3), np.float32)
        for (p0, au, av, eu, ev), tex in zip(self.planes, self.textures):
            n = np.cross(au, av)
            den = d @ n
            with np.errstate(divide="ignore", invalid="ignore"):
                t = ((p0 - c) @ n) / den
            X = c + t[:, None] * d
            a = (X - p0) @ au / eu
            b = (X - p0) @ av / ev
            hit = (t > 1e-6) & (a >= 0) & (a < 1) & (b >= 0) & (b < 1) & (t < best_t)
            S = tex.shape[0]
            tu = np.clip(a[hit] * (S - 1), 0, S - 1.001)
            tv = np.clip(b[hit] * (S - 1), 0, S - 1.001)
            iu, iv = tu.astype(int), tv.astype(int)
            fu, fv = (tu - iu)[:, None], (tv - iv)[:, None]
            img[hit] = (
                (1 - fu) * (1 - fv) * tex[iv, iu]
                + fu * (1 - fv) * tex[iv, iu + 1]
                + (1 - fu) * fv * tex[iv + 1, iu]
                + fu * fv * tex[iv + 1, iu + 1]
            )
            best_t[hit] = t[hit]
        depth = np.where(np.isfinite(best_t), best_t, np.nan).astype(
            np.float32
        )  # z_cam = t since d_cam.z = 1
        return img.reshape(H, W, 3), depth.reshape(H, W)

    def frames(self, poses: list[np.ndarray], with_depth: bool = False) -> list[Frame]:
        out = []
        for i, T in enumerate(poses):
            img, depth = self.render(T)
            out.append(Frame(i, 0.1 * i, img, INTR, depth if with_depth else None, T))
        return out


def forward_motion(n: int, step: float = 0.06, yaw_deg: float = 1.0) -> list[np.ndarray]:
    """Camera moving sideways and forward with a slow yaw: good parallax."""
    return [
        make_T(
            so3_exp(np.array([0.0, np.radians(yaw_deg) * i, 0.0])),
            np.array([step * i, 0.02 * i, 0.5 * step * i]),
        )
        for i in range(n)
    ]


def pure_rotation(n: int, deg: float = 1.5) -> list[np.ndarray]:
    return [make_T(so3_exp(np.array([0.2, 1.0, 0.0]) * np.radians(deg) * i), np.zeros(3)) for i in range(n)]
