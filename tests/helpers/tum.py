"""A minimal reader of TUM RGB-D folders for the tests (frontend, mapping), independent of the loader.

Reads the original layout: rgb.txt, depth.txt (nearest by time), groundtruth.txt through
``gsslam.io.trajectory.read_tum`` (the one TUM parser), depth PNG / 5000 = metres.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from gsslam.geometry import make_T, quat_to_rot, rot_to_quat
from gsslam.io.trajectory import read_tum
from gsslam.types import CameraIntrinsics, Frame, Trajectory

TUM_FR3 = CameraIntrinsics(fx=535.4, fy=539.2, cx=320.1, cy=247.6, width=640, height=480)


def _read_list(path: Path) -> list[tuple[float, str]]:
    rows = []
    for line in path.read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        t, name = line.split()[:2]
        rows.append((float(t), name))
    return rows


def _interpolate(gt: Trajectory, t: float) -> np.ndarray | None:
    """GT pose at ``t``: linear in translation, nlerp in rotation, between samples < 20 ms apart."""
    g_ts = gt.timestamps
    k = int(np.searchsorted(g_ts, t))
    if k == 0 or k >= len(g_ts) or g_ts[k] - g_ts[k - 1] > 0.02:
        return None
    w = (t - g_ts[k - 1]) / (g_ts[k] - g_ts[k - 1])
    qa, qb = rot_to_quat(gt.poses[k - 1, :3, :3]), rot_to_quat(gt.poses[k, :3, :3])  # (qx, qy, qz, qw)
    if qa @ qb < 0:
        qb = -qb
    q = (1 - w) * qa + w * qb  # nlerp: exact enough over 10 ms
    return make_T(
        quat_to_rot(q / np.linalg.norm(q)), (1 - w) * gt.poses[k - 1, :3, 3] + w * gt.poses[k, :3, 3]
    )


def _nearest(gt: Trajectory, t: float) -> np.ndarray:
    return gt.poses[int(np.argmin(np.abs(gt.timestamps - t)))].copy()


def load_tum(root: Path, indices: list[int], gt_pose: str = "interpolate") -> list[Frame]:
    """Frames ``indices`` of rgb.txt with the nearest depth and a GT pose: ``"interpolate"`` (between
    samples < 20 ms apart, else None) or ``"nearest"`` (the closest sample)."""
    rgb = _read_list(root / "rgb.txt")
    depth = _read_list(root / "depth.txt")
    d_ts = np.array([t for t, _ in depth])
    gt = read_tum(root / "groundtruth.txt")
    pose_at = _interpolate if gt_pose == "interpolate" else _nearest
    frames = []
    for i in indices:
        t, name = rgb[i]
        img = cv2.imread(str(root / name), cv2.IMREAD_COLOR)[..., ::-1].astype(np.float32) / 255.0
        j = int(np.argmin(np.abs(d_ts - t)))
        d = cv2.imread(str(root / depth[j][1]), cv2.IMREAD_UNCHANGED).astype(np.float32) / 5000.0
        d[d <= 0] = np.nan
        frames.append(Frame(i, t, np.ascontiguousarray(img), TUM_FR3, d, pose_at(gt, t)))
    return frames


def list_entries(path: Path) -> tuple[list[str], list[str]]:
    """A TUM list file (rgb.txt, depth.txt, groundtruth.txt) as (comment lines, data lines)."""
    lines = path.read_text().splitlines()
    return [l for l in lines if l.startswith("#")], [l for l in lines if l.strip() and not l.startswith("#")]


def copy_tum_prefix(src: Path, dst: Path, n: int) -> Path:
    """The first ``n`` rgb/depth entries of the TUM folder ``src`` (with their files) and the full
    groundtruth.txt, copied into the new folder ``dst``."""
    import shutil

    dst.mkdir(parents=True)
    for lst in ("rgb.txt", "depth.txt"):
        head, rows = list_entries(src / lst)
        (dst / lst).write_text("\n".join(head + rows[:n]) + "\n")
        for row in rows[:n]:
            rel = row.split()[1]
            (dst / rel).parent.mkdir(exist_ok=True)
            shutil.copy(src / rel, dst / rel)
    shutil.copy(src / "groundtruth.txt", dst / "groundtruth.txt")
    return dst
