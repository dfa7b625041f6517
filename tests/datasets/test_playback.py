"""Playback of a real sequence (patterns, pauses, jumps, ground truth) and simulated misregistered depth."""

from __future__ import annotations

import numpy as np
import pytest

from gsslam.datasets.base import open_dataset
from gsslam.datasets.misregistered import Misregistration, MisregistrationError, misregister_depth
from gsslam.datasets.playback import PlaybackError, interpolate_trajectory, playback_plan
from gsslam.geometry import make_T, so3_exp
from gsslam.types import CameraIntrinsics, Trajectory


def test_plan_patterns():
    assert playback_plan(4, "f").tolist() == [0, 1, 2, 3]
    assert playback_plan(4, "fb").tolist() == [0, 1, 2, 3, 2, 1, 0]
    assert playback_plan(4, "fbf").tolist() == [0, 1, 2, 3, 2, 1, 0, 1, 2, 3]
    assert playback_plan(3, "fbfbf").tolist() == [0, 1, 2, 1, 0, 1, 2, 1, 0, 1, 2]
    assert playback_plan(3, "b").tolist() == [2, 1, 0]
    with pytest.raises(PlaybackError):
        playback_plan(4, "fx")
    with pytest.raises(PlaybackError):
        playback_plan(1, "f")


def test_plan_pauses_and_jumps():
    # a pause of 2 after every 3rd played frame
    assert playback_plan(6, "f", pause_every=3, pause_len=2).tolist() == [0, 1, 2, 2, 2, 3, 4, 5, 5, 5]
    # every 2 played frames, skip the next 1
    assert playback_plan(8, "f", jump_every=2, jump_len=1).tolist() == [0, 1, 3, 4, 6, 7]
    # jumps first, then pauses
    plan = playback_plan(8, "f", jump_every=2, jump_len=1, pause_every=2, pause_len=1)
    assert plan.tolist() == [0, 1, 1, 3, 4, 4, 6, 7, 7]
    # a seed moves the phase but keeps the counts
    a = playback_plan(50, "fb", pause_every=10, pause_len=3, seed=3)
    assert len(a) - 99 in (9 * 3, 10 * 3) and a[0] == 0
    with pytest.raises(PlaybackError):
        playback_plan(5, "f", pause_every=-1)


def test_interpolated_ground_truth():
    ts = np.array([0.0, 0.01, 0.02, 0.5])
    R = so3_exp(np.array([0.0, 0.0, 0.2]))
    poses = np.stack([np.eye(4), make_T(R, np.array([1.0, 0, 0])), np.eye(4), np.eye(4)])
    ok, out = interpolate_trajectory(Trajectory(ts, poses), np.array([0.005, 0.01, 0.3, -1.0]), max_gap=0.1)
    assert ok.tolist() == [True, True, False, False]  # 0.3: rows 0.48 s apart; -1: before the first row
    assert np.allclose(out[0][:3, 3], [0.5, 0, 0])
    assert np.allclose(out[0][:3, :3], so3_exp(np.array([0.0, 0.0, 0.1])))
    assert np.allclose(out[1], poses[1])


def test_playback_of_bundled_tum(bundled_tum):
    base = open_dataset("tum", bundled_tum)
    ds = open_dataset("playback", bundled_tum, base="tum", pattern="fbf", n=20, pause_every=7, pause_len=2)
    plan = playback_plan(20, "fbf", pause_every=7, pause_len=2)
    assert len(ds) == len(plan)
    ts = np.array(ds.timestamps())
    assert np.all(np.diff(ts) > 0)
    assert np.allclose(np.diff(ts), np.median(np.diff(base.timestamps()[:20])))
    k = 25  # a frame of the backward part
    f, g = ds[k], base[int(plan[k])]
    assert f.index == k and f.timestamp == ts[k]
    assert np.array_equal(f.image, g.image) and np.array_equal(f.depth, g.depth, equal_nan=True)
    # ground truth: the played frame's pose is the base ground truth at the source frame's time
    gt = ds.ground_truth()
    assert np.all(np.diff(gt.timestamps) > 0)
    src_gt = base.ground_truth()
    ok, want = interpolate_trajectory(src_gt, np.array([base.timestamps()[int(plan[k])]]), 0.1)
    j = int(np.flatnonzero(gt.timestamps == ts[k])[0])
    assert ok[0] and np.allclose(gt.poses[j], want[0])
    assert np.allclose(f.T_world_cam_gt, want[0])
    # the same source frame played twice has the same ground truth
    same = [i for i in range(len(plan)) if plan[i] == plan[k] and i != k]
    assert same and np.allclose(ds[same[0]].T_world_cam_gt, f.T_world_cam_gt)
    # nearest-row GT of the base (what the TUM loader gives per frame) is within a few mm of it
    assert np.linalg.norm(g.T_world_cam_gt[:3, 3] - f.T_world_cam_gt[:3, 3]) < 0.01


K = CameraIntrinsics(500.0, 500.0, 79.5, 59.5, 160, 120)


def _step_depth() -> np.ndarray:
    d = np.full((120, 160), 4.0, dtype=np.float32)
    d[:, :80] = 1.0  # a near surface left of column 80, the wall at 4 m right of it
    return d


def test_misregistration_zero_offset_is_identity():
    d = _step_depth()
    d[5:9, 100:104] = np.nan
    out = misregister_depth(d, K, baseline_m=0.0, focal_scale=1.0)
    assert np.array_equal(out, d, equal_nan=True)


def test_misregistration_moves_an_edge_by_the_disparity():
    d = _step_depth()
    b = 0.02  # the depth camera 2 cm to the right: a point at z moves left by f b / z px
    out = misregister_depth(d, K, baseline_m=b, focal_scale=1.0)
    row = out[60]
    near_end = int(np.flatnonzero(row < 2.0)[-1])  # last pixel of the near surface (colour: 79)
    wall_start = int(np.flatnonzero(row > 2.0)[0])  # first wall pixel (colour: 80)
    # the near edge moves by 500 * 0.02 / 1 = 10 px, the wall by 500 * 0.02 / 4 = 2.5 px
    assert abs(near_end - (79 - 10)) <= 1 and abs(wall_start - (80 - 2.5)) <= 1
    # between them the wall the colour camera could not see: no depth (a Kinect shadow)
    assert np.all(np.isnan(row[near_end + 1 : wall_start]))
    # the right border loses the wall's last 2.5 px (seen by the colour camera only)
    assert np.isnan(row[-1])


def test_misregistration_focal_scale_magnifies_about_the_centre():
    d = _step_depth()
    out = misregister_depth(d, K, baseline_m=0.0, focal_scale=1.2)
    edge = int(np.flatnonzero(out[60] > 2.0)[0])
    assert abs(edge - (79.5 + (80 - 79.5) * 1.2)) <= 1
    assert np.all(np.isfinite(out))  # magnified: no cracks, no border
    shrunk = misregister_depth(d, K, baseline_m=0.0, focal_scale=0.8)
    assert np.isnan(shrunk[0, 0]) and np.isfinite(shrunk[60, 80])


def test_playback_misregistered(bundled_tum):
    mr = {"baseline_m": 0.025, "focal_scale": 1.1, "report": "depth"}
    ds = open_dataset("playback", bundled_tum, pattern="f", n=3, misregister=mr)
    base = open_dataset("tum", bundled_tum)
    f = ds[1]
    assert np.isclose(f.intrinsics.fx, base.intrinsics.fx * 1.1)
    assert f.depth.shape == base[1].depth.shape
    assert not np.array_equal(f.depth, base[1].depth, equal_nan=True)
    with pytest.raises(MisregistrationError):
        Misregistration.from_dict({"baseline": 0.02})
    with pytest.raises(MisregistrationError):
        Misregistration(report="ir")
    with pytest.raises(MisregistrationError):
        Misregistration(ground_truth="ir")


def test_playback_ground_truth_of_the_depth_camera(bundled_tum):
    """7-Scenes' ground truth poses the depth camera: ``ground_truth: depth`` gives the colour camera's true
    poses moved to the depth camera, 25 mm along each pose's own x; the frames' images are unchanged."""
    mr = {"baseline_m": 0.025, "focal_scale": 1.1, "report": "depth"}
    colour = open_dataset("playback", bundled_tum, pattern="f", n=20, misregister=mr)
    depth = open_dataset("playback", bundled_tum, pattern="f", n=20, misregister={**mr, "ground_truth": "depth"})
    assert colour.ground_truth_camera == "colour" and depth.ground_truth_camera == "depth"
    gc, gd = colour.ground_truth(), depth.ground_truth()
    offset = np.einsum("nij,nj->ni", np.linalg.inv(gc.poses), np.c_[gd.positions, np.ones(len(gd))])[:, :3]
    np.testing.assert_allclose(offset, np.tile([0.025, 0.0, 0.0], (len(gd), 1)), atol=1e-9)
    np.testing.assert_allclose(gd.poses[:, :3, :3], gc.poses[:, :3, :3])
    k = int(np.flatnonzero(np.isin(depth.timestamps(), gd.timestamps))[0])  # a frame with ground truth
    j = int(np.flatnonzero(gd.timestamps == depth.timestamps()[k])[0])
    np.testing.assert_allclose(depth[k].T_world_cam_gt, gd.poses[j], atol=1e-12)
    np.testing.assert_array_equal(depth[k].image, colour[k].image)
