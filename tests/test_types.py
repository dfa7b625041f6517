import numpy as np
import pytest

from gsslam.types import CameraIntrinsics, Correspondences, Frame, SubmapEncoding, Trajectory, TypesError


def _K():
    return CameraIntrinsics(fx=535.4, fy=539.2, cx=320.1, cy=247.6, width=640, height=480)


def test_intrinsics_scaling_keeps_pixel_centres():
    K = _K()
    half = K.scaled(0.5)
    assert (half.width, half.height) == (320, 240)
    # a point projecting to pixel (u, v) at full res projects to ((u + .5) / 2 - .5) at half res
    X = np.array([0.3, -0.2, 2.0])
    u_full = K.fx * X[0] / X[2] + K.cx
    u_half = half.fx * X[0] / X[2] + half.cx
    assert np.isclose(u_half, (u_full + 0.5) * 0.5 - 0.5)


def test_intrinsics_reject_nonsense():
    with pytest.raises(TypesError, match="positive"):
        CameraIntrinsics(fx=0, fy=1, cx=0, cy=0, width=10, height=10)
    with pytest.raises(TypesError, match="size"):
        CameraIntrinsics(fx=1, fy=1, cx=0, cy=0, width=0, height=10)


def test_frame_checks_shapes():
    K = CameraIntrinsics(10, 10, 2, 2, width=4, height=3)
    Frame(0, 0.0, np.zeros((3, 4, 3), np.float32), K, depth=np.ones((3, 4), np.float32))
    with pytest.raises(TypesError, match="intrinsics say"):
        Frame(0, 0.0, np.zeros((4, 4, 3), np.float32), K)
    with pytest.raises(TypesError, match="registered"):
        Frame(0, 0.0, np.zeros((3, 4, 3), np.float32), K, depth=np.ones((2, 4), np.float32))


def test_trajectory_validation_and_path_length():
    poses = np.tile(np.eye(4), (3, 1, 1))
    poses[1, 0, 3] = 1.0
    poses[2, 0, 3] = 3.0
    traj = Trajectory([0.0, 1.0, 2.0], poses)
    assert len(traj) == 3 and np.isclose(traj.path_length(), 3.0)
    with pytest.raises(TypesError, match="must match"):
        Trajectory([0.0, 1.0], poses)


def test_submap_encoding_and_correspondence_shapes():
    K = CameraIntrinsics(10, 10, 2, 2, width=4, height=3)
    SubmapEncoding([0, 1], np.tile(np.eye(4), (2, 1, 1)), np.zeros((2, 3, 4, 3)), np.zeros((2, 3, 4)), K)
    with pytest.raises(TypesError, match="T_local_cam"):
        SubmapEncoding(
            [0, 1, 2], np.tile(np.eye(4), (2, 1, 1)), np.zeros((3, 3, 4, 3)), np.zeros((3, 3, 4)), K
        )
    c = Correspondences(0, 1, np.zeros((5, 2)), np.zeros((5, 2)), np.ones(5), np.ones(5))
    assert len(c) == 5
    with pytest.raises(TypesError, match="depth_src"):
        Correspondences(0, 1, np.zeros((5, 2)), np.zeros((5, 2)), np.ones(4), np.ones(5))
