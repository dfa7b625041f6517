"""Single-frame PnP outliers are found against the keyframes' path; smooth motion is left alone."""

from __future__ import annotations

import numpy as np

from gsslam.frontend.pose_outliers import find_pose_outliers
from gsslam.geometry import make_T, so3_exp


def _path(n=40):
    # a smooth hand-held-like motion: 1 cm and 0.3 deg per frame with a gentle curve
    poses = {}
    for i in range(n):
        R = so3_exp(np.array([0.0, np.radians(0.3) * i, 0.0]))
        poses[i] = make_T(R, np.array([0.01 * i, 0.002 * np.sin(i / 5.0), 0.0]))
    return poses, {i: 0.033 * i for i in range(n)}, set(range(0, 40, 6))


def test_smooth_motion_has_no_outliers():
    poses, ts, kfs = _path()
    assert find_pose_outliers(poses, kfs, ts) == []


def test_a_frame_off_by_centimetres_or_degrees_is_found():
    poses, ts, kfs = _path()
    poses[8] = poses[8] @ make_T(np.eye(3), np.array([0.0, 0.06, 0.0]))  # 6 cm off (the teddy outliers: 9-15 cm)
    poses[21] = poses[21] @ make_T(so3_exp(np.array([0.0, 0.0, np.radians(8.0)])), np.zeros(3))
    poses[2] = poses[2] @ make_T(np.eye(3), np.array([0.0, 0.01, 0.0]))  # 1 cm: within the bound
    assert find_pose_outliers(poses, kfs, ts) == [8, 21]


def test_keyframes_and_frames_after_the_last_keyframe_are_not_judged():
    poses, ts, kfs = _path()
    poses[39] = poses[39] @ make_T(np.eye(3), np.array([0.0, 0.5, 0.0]))
    poses[12] = poses[12] @ make_T(np.eye(3), np.array([0.0, 0.05, 0.0]))  # a keyframe
    found = find_pose_outliers(poses, kfs, ts)
    assert 39 not in found and 12 not in found
