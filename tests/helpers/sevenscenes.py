"""A tiny 7-Scenes sequence in the original layout (no real 7-Scenes data is available offline): random
colour images, depth in millimetres with the invalid codes 0 and 65535, 4x4 camera-to-world pose files."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from gsslam.geometry import make_T, so3_exp


def write_sequence(seq: Path, n: int = 3, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    seq.mkdir(parents=True)
    truth = {"color": [], "depth_mm": [], "pose": []}
    for i in range(n):
        color = rng.integers(0, 256, (480, 640, 3), dtype=np.uint8)
        depth = rng.integers(400, 4000, (480, 640)).astype(np.uint16)
        depth[:10] = 0
        depth[-10:] = 65535
        T = make_T(so3_exp(rng.normal(size=3)), rng.normal(size=3))
        cv2.imwrite(str(seq / f"frame-{i:06d}.color.png"), color)
        cv2.imwrite(str(seq / f"frame-{i:06d}.depth.png"), depth)
        np.savetxt(seq / f"frame-{i:06d}.pose.txt", T, fmt="%.9e")
        truth["color"].append(color[:, :, ::-1] / 255.0)
        truth["depth_mm"].append(depth)
        truth["pose"].append(T)
    return truth
