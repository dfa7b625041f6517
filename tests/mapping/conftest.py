"""Frames of the bundled TUM fr3/teddy sequence with ground-truth poses, read directly (no loader)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from gsslam.geometry import make_T, quat_to_rot
from gsslam.types import CameraIntrinsics, Frame

TUM_FR3 = CameraIntrinsics(535.4, 539.2, 320.1, 247.6, 640, 480)


def _rows(path: Path) -> list[list[str]]:
    return [ln.split() for ln in path.read_text().splitlines() if ln.strip() and not ln.startswith("#")]


def load_tum_frames(root: Path, indices: list[int]) -> list[Frame]:
    """Frames ``indices`` of a TUM folder (nearest depth and GT pose by timestamp)."""
    rgb = _rows(root / "rgb.txt")
    depth = _rows(root / "depth.txt")
    gt = np.array([[float(v) for v in r] for r in _rows(root / "groundtruth.txt")])
    d_t = np.array([float(r[0]) for r in depth])
    frames = []
    for i in indices:
        t = float(rgb[i][0])
        img = cv2.imread(str(root / rgb[i][1]), cv2.IMREAD_COLOR)[..., ::-1].astype(np.float32) / 255.0
        d_raw = cv2.imread(str(root / depth[int(np.argmin(np.abs(d_t - t)))][1]), cv2.IMREAD_UNCHANGED)
        dep = np.where(d_raw > 0, d_raw.astype(np.float32) / 5000.0, np.nan).astype(np.float32)
        g = gt[int(np.argmin(np.abs(gt[:, 0] - t)))]
        T = make_T(quat_to_rot(g[4:8]), g[1:4])
        frames.append(Frame(i, t, np.ascontiguousarray(img), TUM_FR3, dep, T))
    return frames


@pytest.fixture(scope="session")
def teddy_frames(bundled_tum) -> list[Frame]:
    """Frames 5, 10, 15, 20 (after the first GT pose), 640x480 with depth and GT pose."""
    return load_tum_frames(bundled_tum, [5, 10, 15, 20])


@pytest.fixture(scope="session")
def teddy_sequence(bundled_tum) -> list[Frame]:
    """Six frames 10 apart (5, 15, ..., 55: about 25 cm of camera motion) with depth and GT pose."""
    return load_tum_frames(bundled_tum, [5, 15, 25, 35, 45, 55])
