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

That line is wrong where the camera turns back between two keyframes: on TUM teddy played at 3x speed
forward-backward, the frames at the playback's direction reversals were 3.3 cm off the line (their tracks
0.4 cm off the truth). With ``motion_check`` a flagged frame is judged a second time against the motion
of the frames around it (:func:`agrees_with_motion`): a failed track is isolated, a curved path is not.
A flagged frame within ``max_dev_m`` / ``max_dev_deg`` of the constant-velocity prediction from the two
unflagged frames before it, or of that from the two after it, keeps its pose. On the same runs the
reversal frames were 0.5-0.7 cm from those predictions, the failed tracks (teddy 200, its
forward-backward playback and the 3x row) 10-16 cm from both (docs/results.md, "The pose-outlier check
at direction reversals, session 12").
"""

from __future__ import annotations

import numpy as np

from gsslam.geometry import so3_exp, so3_log


def _interp(Ta: np.ndarray, Tb: np.ndarray, u: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Ta[:3, :3] @ so3_exp(u * so3_log(Ta[:3, :3].T @ Tb[:3, :3]))
    T[:3, 3] = (1.0 - u) * Ta[:3, 3] + u * Tb[:3, 3]
    return T


def _extrapolate(Ta: np.ndarray, Tb: np.ndarray, ta: float, tb: float, t: float) -> np.ndarray:
    """``Tb`` moved on by the motion ``Ta -> Tb`` (in the world frame) to time ``t``, at constant velocity."""
    u = (t - tb) / (tb - ta)
    T = np.eye(4)
    T[:3, :3] = so3_exp(u * so3_log(Tb[:3, :3] @ Ta[:3, :3].T)) @ Tb[:3, :3]
    T[:3, 3] = Tb[:3, 3] + u * (Tb[:3, 3] - Ta[:3, 3])
    return T


def _close(A: np.ndarray, B: np.ndarray, max_m: float, max_deg: float) -> bool:
    dev_deg = float(np.degrees(np.linalg.norm(so3_log(A[:3, :3].T @ B[:3, :3]))))
    return float(np.linalg.norm(A[:3, 3] - B[:3, 3])) <= max_m and dev_deg <= max_deg


def agrees_with_motion(
    poses: dict[int, np.ndarray],  # frame -> T_world_cam [4, 4]
    candidates: list[int],  # frames to judge (the flagged ones)
    timestamps: dict[int, float],  # frame -> seconds
    max_dev_m: float = 0.02,
    max_dev_deg: float = 3.0,
) -> list[int]:
    """The candidates whose pose lies within ``max_dev_m`` / ``max_dev_deg`` of a constant-velocity
    prediction through their neighbours: the two nearest posed frames before them (in time), or the two
    after them, candidates not among them. A side with fewer than two such frames predicts nothing. A
    candidate kept joins the neighbours of the rest, and the rest are judged again (a turn that spans
    several frames between two keyframes is kept from its ends inwards; a failed track stays isolated)."""
    rest = {f for f in candidates if f in poses and f in timestamps}
    kept: list[int] = []
    while rest:
        known = sorted((timestamps[i], i) for i in poses if i in timestamps and i not in rest)
        kt = np.array([t for t, _ in known])
        now = []
        for f in sorted(rest):
            t = timestamps[f]
            j = int(np.searchsorted(kt, t))
            sides = []
            if j >= 2:
                sides.append((known[j - 2], known[j - 1]))
            if j + 1 < len(known):
                sides.append((known[j + 1], known[j]))
            for (ta, a), (tb, b) in sides:
                pred = _extrapolate(poses[a], poses[b], ta, tb, t) if ta != tb else None
                if pred is not None and _close(poses[f], pred, max_dev_m, max_dev_deg):
                    now.append(f)
                    break
        if not now:
            break
        kept += now
        rest -= set(now)
    return sorted(kept)


def find_pose_outliers(
    poses: dict[int, np.ndarray],  # frame -> T_world_cam [4, 4]
    keyframes: set[int],  # frames whose poses are trusted (the graph's keyframes)
    timestamps: dict[int, float],  # frame -> seconds
    max_dev_m: float = 0.02,
    max_dev_deg: float = 3.0,
    rel: float = 0.5,
    motion_check: bool = False,
) -> list[int]:
    """Non-keyframes whose pose leaves the keyframes' path (module docstring), sorted; with
    ``motion_check`` not those that follow the motion of the frames around them."""
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
    if motion_check:
        keep = set(agrees_with_motion(poses, out, timestamps, max_dev_m, max_dev_deg))
        out = [f for f in out if f not in keep]
    return sorted(out)
