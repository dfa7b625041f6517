"""A minimal reader of TUM RGB-D folders for the frontend tests and measurements.

Kept here (not in gsslam.datasets) so the frontend tests depend only on the frontend; it reads
the original layout: rgb.txt, depth.txt, groundtruth.txt, depth PNG / 5000 = metres.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from gsslam.geometry import make_T, quat_to_rot
from gsslam.types import CameraIntrinsics, Frame

TUM_FR3 = CameraIntrinsics(fx=535.4, fy=539.2, cx=320.1, cy=247.6, width=640, height=480)


def _read_list(path: Path) -> list[tuple[float, list[str]]]:
    rows = []
    for line in path.read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        parts = line.split()
        rows.append((float(parts[0]), parts[1:]))
    return rows


def _nearest(ts: np.ndarray, t: float) -> int:
    return int(np.argmin(np.abs(ts - t)))


def _interpolate(g_ts: np.ndarray, gt: list, t: float) -> np.ndarray | None:
    """GT pose at ``t``: linear in translation, slerp in rotation, between samples < 20 ms apart."""
    k = int(np.searchsorted(g_ts, t))
    if k == 0 or k >= len(g_ts) or g_ts[k] - g_ts[k - 1] > 0.02:
        return None
    a = np.array([float(x) for x in gt[k - 1][1]])
    b = np.array([float(x) for x in gt[k][1]])
    w = (t - g_ts[k - 1]) / (g_ts[k] - g_ts[k - 1])
    qa, qb = a[3:7] / np.linalg.norm(a[3:7]), b[3:7] / np.linalg.norm(b[3:7])
    if qa @ qb < 0:
        qb = -qb
    q = (1 - w) * qa + w * qb  # nlerp: exact enough over 10 ms
    return make_T(quat_to_rot(q / np.linalg.norm(q)), (1 - w) * a[:3] + w * b[:3])


def load_tum(root: Path, indices: list[int]) -> list[Frame]:
    """Frames ``indices`` of the rgb.txt list, with associated depth and (nearest, < 20 ms) GT pose."""
    rgb = _read_list(root / "rgb.txt")
    depth = _read_list(root / "depth.txt")
    d_ts = np.array([t for t, _ in depth])
    gt = _read_list(root / "groundtruth.txt")
    g_ts = np.array([t for t, _ in gt])
    frames = []
    for i in indices:
        t, (name,) = rgb[i]
        img = cv2.imread(str(root / name), cv2.IMREAD_COLOR)[..., ::-1].astype(np.float32) / 255.0
        j = _nearest(d_ts, t)
        d = cv2.imread(str(root / depth[j][1][0]), cv2.IMREAD_UNCHANGED).astype(np.float32) / 5000.0
        d[d <= 0] = np.nan
        pose = _interpolate(g_ts, gt, t)
        frames.append(Frame(i, t, np.ascontiguousarray(img), TUM_FR3, d, pose))
    return frames
