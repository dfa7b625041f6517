"""The synthetic dataset's ``depth_delay_s``: the depth image taken at another time than the colour image."""

from __future__ import annotations

import numpy as np
import pytest

from gsslam.datasets.synthetic import SyntheticDataset, SyntheticDatasetError
from gsslam.datasets.synthetic.dataset import delayed_poses
from gsslam.geometry import so3_log

KW = dict(n_frames=60, width=64, height=48, scene="furnished_room", trajectory="room_walk", seed=0)
MIS = {"baseline_m": 0.025, "focal_scale": 1.114, "report": "depth"}


def test_zero_delay_hands_out_the_same_frames_and_truth():
    hand = dict(sensor="kinect_v1", misregister={**MIS, "ground_truth": "depth"}, degrade={"shutter": 0.5})
    a, b = SyntheticDataset(**KW, **hand), SyntheticDataset(**KW, **hand, depth_delay_s=0.0)
    for i in (0, 31, 59):
        fa, fb = a[i], b[i]
        np.testing.assert_array_equal(fa.image, fb.image)
        np.testing.assert_array_equal(fa.depth, fb.depth)
        np.testing.assert_array_equal(fa.T_world_cam_gt, fb.T_world_cam_gt)
    np.testing.assert_array_equal(a.ground_truth().poses, b.ground_truth().poses)


def test_a_whole_frame_late_depth_is_the_next_frames_depth():
    """Delay 1 / fps: frame k's depth is frame k + 1's (interpolation reaches the next pose; the last frame's
    is extrapolated along the last step); the colour image and the colour truth stay frame k's."""
    now = SyntheticDataset(**KW, misregister=MIS)
    late = SyntheticDataset(**KW, misregister=MIS, depth_delay_s=1.0 / 30.0)
    for k in (10, 40):
        np.testing.assert_array_equal(late[k].image, now[k].image)
        np.testing.assert_array_equal(late[k].T_world_cam_gt, now[k].T_world_cam_gt)
        d_late, d_next = late[k].depth, now[k + 1].depth
        both = np.isfinite(d_late) & np.isfinite(d_next)
        assert both.mean() > 0.9 and np.abs(d_late[both] - d_next[both]).max() < 1e-4
        moved = np.isfinite(now[k].depth) & both
        assert np.median(np.abs(now[k].depth[moved] - d_late[moved])) > 1e-4  # the camera did move
    T = SyntheticDataset(**KW)._poses
    ext = delayed_poses(T, 1.0)[-1]  # past the end: the last step once more (translation in the world)
    np.testing.assert_allclose(ext[:3, 3], 2 * T[-1][:3, 3] - T[-2][:3, 3], atol=1e-12)
    np.testing.assert_allclose(T[-1][:3, :3].T @ ext[:3, :3], T[-2][:3, :3].T @ T[-1][:3, :3], atol=1e-9)


def test_half_frame_delay_and_the_depth_cameras_truth_at_its_time():
    """Half a frame early: the depth camera's ground truth (7-Scenes' convention) is the colour camera's
    halfway pose moved by the baseline; the colour camera's truth stays at the colour time."""
    d = -0.5 / 30.0
    col = SyntheticDataset(**KW, misregister=MIS, depth_delay_s=d)
    dep = SyntheticDataset(**KW, misregister={**MIS, "ground_truth": "depth"}, depth_delay_s=d)
    T = SyntheticDataset(**KW)._poses
    np.testing.assert_array_equal(col.ground_truth().poses, T)
    gt = dep.ground_truth().poses
    k = 30
    np.testing.assert_allclose(gt[k][:3, :3] @ np.array([-0.025, 0, 0]) + gt[k][:3, 3],
                               0.5 * (T[k - 1][:3, 3] + T[k][:3, 3]), atol=1e-12)  # fmt: skip
    half = so3_log(T[k - 1][:3, :3].T @ gt[k][:3, :3])
    np.testing.assert_allclose(half, 0.5 * so3_log(T[k - 1][:3, :3].T @ T[k][:3, :3]), atol=1e-12)
    np.testing.assert_array_equal(dep[k].T_world_cam_gt, gt[k])


def test_delay_is_at_most_one_frame():
    with pytest.raises(SyntheticDatasetError, match="depth_delay_s"):
        SyntheticDataset(**KW, depth_delay_s=0.05)
    with pytest.raises(SyntheticDatasetError, match="depth_delay_s"):
        SyntheticDataset(**KW, depth_delay_s=float("nan"))
