"""Single-frame pose outliers: a tracked frame whose pose leaves the path its keyframes draw.

A non-keyframe gets its pose from one PnP against its reference keyframe. On real data a few of
these are wrong by 5-15 cm (motion blur, flow on a repeated texture, depth of the wrong surface at an
edge) while the keyframes around them are right; on TUM teddy played forward-backward-forward, 3 of
577 frames held a third of the RGB-D ATE (docs/results.md, "Accuracy at length").

:func:`find_pose_outliers` compares each non-keyframe with the interpolation (in time: linear
translation, geodesic rotation) between the nearest keyframes before and after it. The camera moves
smoothly between two keyframes (at most ``keyframes.max_gap`` frames apart), so a frame may leave
that line only by a fraction of the keyframes' own distance::

    |t - t_interp| > max_dev_m + rel * |t_kf_after - t_kf_before|     or the same for the rotation angle

Frames before the first or after the last keyframe are not judged. The caller re-interpolates the
outliers from their posed neighbours.
"""

from __future__ import annotations

import numpy as np

from gsslam.geometry import so3_exp, so3_log


def _interp(Ta: np.ndarray, Tb: np.ndarray, u: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Ta[:3, :3] @ so3_exp(u * so3_log(Ta[:3, :3].T @ Tb[:3, :3]))
    T[:3, 3] = (1.0 - u) * Ta[:3, 3] + u * Tb[:3, 3]
    return T


def find_pose_outliers(
    poses: dict[int, np.ndarray],  # frame -> T_world_cam [4, 4]
    keyframes: set[int],  # frames whose poses are trusted (the graph's keyframes)
    timestamps: dict[int, float],  # frame -> seconds
    max_dev_m: float = 0.02,
    max_dev_deg: float = 3.0,
    rel: float = 0.5,
) -> list[int]:
    """Non-keyframes whose pose leaves the keyframes' path (module docstring), sorted."""
    kfs = sorted((timestamps[k], k) for k in keyframes if k in poses and k in timestamps)
    if len(kfs) < 2:
        return []
    kt = np.array([t for t, _ in kfs])
    out = []
    for f, T in poses.items():
        if f in keyframes or f not in timestamps:
            continue
        t = timestamps[f]
        j = int(np.searchsorted(kt, t))
        if j == 0 or j == len(kt):
            continue
        (ta, a), (tb, b) = kfs[j - 1], kfs[j]
        Ta, Tb = poses[a], poses[b]
        Ti = _interp(Ta, Tb, 0.0 if tb == ta else (t - ta) / (tb - ta))
        gap_m = float(np.linalg.norm(Tb[:3, 3] - Ta[:3, 3]))
        gap_deg = float(np.degrees(np.linalg.norm(so3_log(Ta[:3, :3].T @ Tb[:3, :3]))))
        dev_m = float(np.linalg.norm(T[:3, 3] - Ti[:3, 3]))
        dev_deg = float(np.degrees(np.linalg.norm(so3_log(Ti[:3, :3].T @ T[:3, :3]))))
        if dev_m > max_dev_m + rel * gap_m or dev_deg > max_dev_deg + rel * gap_deg:
            out.append(f)
    return sorted(out)
