"""The ``planes`` preset as the frontend encoder tests use it: a 320 x 240 camera, Frames."""

from __future__ import annotations

import numpy as np

from gsslam.datasets.synthetic import planes
from gsslam.datasets.synthetic.trajectories import forward_motion, pure_rotation  # noqa: F401
from gsslam.types import CameraIntrinsics, Frame

INTR = CameraIntrinsics(fx=260.0, fy=260.0, cx=159.5, cy=119.5, width=320, height=240)


class PlaneScene:
    def __init__(self, seed: int = 0) -> None:
        self.scene = planes(seed)

    def render(self, T_world_cam: np.ndarray, intr: CameraIntrinsics = INTR) -> tuple[np.ndarray, np.ndarray]:
        """-> image [H, W, 3] float32, depth [H, W] float32 (z, NaN where no plane is hit)."""
        img, depth = self.scene.cast(T_world_cam, intr)
        return img, depth.astype(np.float32)

    def frames(self, poses, with_depth: bool = False) -> list[Frame]:
        out = []
        for i, T in enumerate(poses):
            img, depth = self.render(T)
            out.append(Frame(i, 0.1 * i, img, INTR, depth if with_depth else None, T))
        return out
