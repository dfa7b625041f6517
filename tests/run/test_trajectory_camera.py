"""Which camera trajectory.tum is: the ground truth's (7-Scenes: the depth camera, 2.5 cm beside the colour
camera), from the run's registration estimate; the colour camera's poses are kept beside it for the images."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from gsslam.eval.ate import compute_ate
from gsslam.geometry import interpolate_pose, make_T, so3_exp
from gsslam.run.trajectory_camera import COLOUR, image_poses_file, trajectory_camera
from gsslam.types import Trajectory


class _Data:  # a dataset as trajectory_camera sees it
    def __init__(self, camera: str | None):
        if camera is not None:
            self.ground_truth_camera = camera


def _beside(b: float) -> np.ndarray:  # a depth camera b metres along the colour camera's x
    T = np.eye(4)
    T[0, 3] = b
    return T


def _turning_walk(n: int = 200) -> np.ndarray:  # [n, 4, 4] colour camera: a 2 m circle, one full turn in yaw
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.stack([make_T(so3_exp(np.array([0.0, t + 0.3 * np.sin(3 * t), 0.0])),
                            np.array([np.cos(t), 0.1 * np.sin(2 * t), np.sin(t)])) for t in a])  # fmt: skip


def test_choice():
    assert trajectory_camera("ground_truth", _Data(None), _beside(0.025)) is COLOUR  # says nothing
    assert trajectory_camera("ground_truth", _Data("colour"), _beside(0.025)) is COLOUR
    cam = trajectory_camera("ground_truth", _Data("depth"), _beside(0.025))
    assert cam.name == "depth" and not cam.is_colour
    np.testing.assert_allclose(cam.T_colour_cam[:3, 3], [0.025, 0, 0])
    assert trajectory_camera("colour", _Data("depth"), _beside(0.025)) is COLOUR
    assert trajectory_camera("depth", _Data(None), _beside(-0.02)).T_colour_cam[0, 3] == -0.02
    with pytest.raises(ValueError, match="trajectory_camera"):
        trajectory_camera("ir", _Data(None), _beside(0.025))


def test_without_a_registration_the_colour_camera_is_written_with_a_warning(caplog):
    with caplog.at_level(logging.WARNING, logger="gsslam.run.trajectory_camera"):
        cam = trajectory_camera("ground_truth", _Data("depth"), None)  # mono: no metric baseline
    assert cam.is_colour and "lever arm" in caplog.text


def test_the_lever_arm_is_error_a_turning_walk_cannot_align_away():
    """A colour camera's exact trajectory against its depth camera's ground truth, 25 mm beside it: the turns
    leave ~the whole lever arm as ATE after SE(3) alignment; moved to the depth camera it is exact."""
    colour = _turning_walk()
    t = np.arange(len(colour)) / 30.0
    cam = trajectory_camera("ground_truth", _Data("depth"), _beside(0.025))
    gt = Trajectory(t, colour @ cam.T_colour_cam)
    as_colour, _ = compute_ate(gt, Trajectory(t, colour), align="se3")
    as_depth, _ = compute_ate(gt, Trajectory(t, np.stack(list(cam.apply(dict(enumerate(colour))).values()))),
                              align="se3")  # fmt: skip
    assert 0.022 < as_colour.stats.rmse < 0.027  # measured 0.0250: a full turn, the mean of R x is ~0
    assert as_depth.stats.rmse < 1e-9


def test_image_poses_file(tmp_path):
    (tmp_path / "keyframes.tum").write_text("")
    assert image_poses_file(tmp_path, "keyframes") == tmp_path / "keyframes.tum"
    (tmp_path / "keyframes_colour.tum").write_text("")
    assert image_poses_file(tmp_path, "keyframes") == tmp_path / "keyframes_colour.tum"


@pytest.mark.slow
def test_a_run_writes_the_ground_truths_camera(bundled_tum, tmp_path):
    """A 7-Scenes-like playback (unregistered depth, ground truth of the depth camera): trajectory.tum is the
    colour camera's poses moved by the run's own baseline estimate; trajectory_colour.tum is what a run with
    ``run.trajectory_camera=colour`` writes, byte for byte; metrics.json says which camera."""
    from gsslam.config import load_config
    from gsslam.datasets.base import open_dataset
    from gsslam.io.trajectory import read_tum
    from gsslam.run.sequence import run_dataset

    mr = {"baseline_m": 0.025, "focal_scale": 1.114, "report": "depth", "ground_truth": "depth"}
    sets = ["mapper.enabled=false", "loop.enabled=false"]
    runs = {}
    for camera in ("ground_truth", "colour"):
        ds = open_dataset("playback", bundled_tum, pattern="f", n=40, misregister=mr)
        cfg = load_config(None, [*sets, f"run.trajectory_camera={camera}"], mode="rgbd")
        runs[camera] = run_dataset(ds, cfg, tmp_path / camera, max_frames=40).metrics
    m, out = runs["ground_truth"], tmp_path / "ground_truth"
    b = m["colour_focal"]["baseline_m_applied"]
    assert abs(b - 0.025) < 0.005  # measured 26.2 mm
    assert m["trajectory_camera"]["camera"] == "depth" and m["trajectory_camera"]["T_colour_camera"][0][3] == b
    assert runs["colour"]["trajectory_camera"]["camera"] == "colour"
    assert (out / "trajectory_colour.tum").read_bytes() == (tmp_path / "colour" / "trajectory.tum").read_bytes()
    assert (out / "keyframes_colour.tum").read_bytes() == (tmp_path / "colour" / "keyframes.tum").read_bytes()
    assert not (tmp_path / "colour" / "trajectory_colour.tum").exists()
    depth, colour = read_tum(out / "trajectory.tum"), read_tum(out / "trajectory_colour.tum")
    moved = np.einsum("nij,nj->ni", np.linalg.inv(colour.poses), np.c_[depth.positions, np.ones(len(depth))])
    np.testing.assert_allclose(moved[:, :3], np.tile([b, 0, 0], (len(depth), 1)), atol=2e-6)  # TUM's digits
    # both against the depth camera's truth: measured 0.126 cm, 0.240 cm as the colour camera
    assert m["ate"]["rmse_m"] < 0.7 * runs["colour"]["ate"]["rmse_m"]


def test_depth_camera_at_the_depth_images_time():
    """With a delay given (encoder.depth_delay_s) the depth camera is written at its image's time, t + tau
    (7-Scenes' truth): ~0.8 cm from the depth camera at the colour image's time on this walk, 8 ms late."""
    walk = _turning_walk(200)
    ts = {i: i / 30.0 for i in range(200)}
    T_cd = _beside(0.025)
    tau = 0.008
    later = {i: interpolate_pose(walk[i], walk[i + 1], tau * 30.0) @ T_cd for i in range(199)}  # the truth
    cam = trajectory_camera("ground_truth", _Data("depth"), T_cd, tau)
    assert cam.record()["delay_s"] == tau
    poses = {i: walk[i] for i in range(200)}
    at_depth_time, at_colour_time = cam.apply(poses, ts), cam.apply(poses)  # without timestamps: colour time
    err = [np.linalg.norm(at_depth_time[i][:3, 3] - later[i][:3, 3]) for i in range(1, 199)]
    err0 = [np.linalg.norm(at_colour_time[i][:3, 3] - later[i][:3, 3]) for i in range(1, 199)]
    assert max(err) < 3e-4 < 0.003 < np.median(err0)  # measured 0.14 mm (centred vs forward velocity) / 7.6 mm
    kf = cam.apply({10: poses[10], 20: poses[20]}, ts, velocity_from=poses)  # keyframes: every frame's velocity
    np.testing.assert_array_equal(kf[20], at_depth_time[20])
    undelayed = trajectory_camera("ground_truth", _Data("depth"), T_cd)
    assert "delay_s" not in undelayed.record()
    np.testing.assert_array_equal(undelayed.apply(poses, ts)[5], poses[5] @ T_cd)
