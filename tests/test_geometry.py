import numpy as np
import pytest

from gsslam import geometry as g


@pytest.fixture
def rng():
    return np.random.default_rng(42)


def test_so3_exp_log_round_trip(rng):
    for _ in range(200):
        w = rng.normal(size=3) * rng.uniform(0, 3)
        R = g.so3_exp(w)
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.isclose(np.linalg.det(R), 1.0)
        assert np.allclose(g.so3_exp(g.so3_log(R)), R, atol=1e-9)


def test_so3_log_near_pi():
    axis = np.array([1.0, 2.0, -0.5]) / np.linalg.norm([1.0, 2.0, -0.5])
    R = g.so3_exp(axis * (np.pi - 1e-7))
    assert np.allclose(g.so3_exp(g.so3_log(R)), R, atol=1e-6)


def test_quaternion_round_trip_and_order(rng):
    # 90 deg about z: (qx, qy, qz, qw) = (0, 0, sin45, cos45)
    q = np.array([0.0, 0.0, np.sqrt(0.5), np.sqrt(0.5)])
    assert np.allclose(g.quat_to_rot(q) @ [1, 0, 0], [0, 1, 0])
    Rs = np.stack([g.so3_exp(rng.normal(size=3)) for _ in range(50)])
    qs = g.rot_to_quat(Rs)
    assert qs.shape == (50, 4)
    assert np.all(qs[:, 3] >= 0)
    assert np.allclose(g.quat_to_rot(qs), Rs, atol=1e-9)


def test_sim3_invert_and_split(rng):
    T = g.make_T(g.so3_exp(rng.normal(size=3)), rng.normal(size=3), s=2.5)
    R, t, s = g.split_sim3(T)
    assert np.isclose(s, 2.5)
    assert np.allclose(g.invert_T(T) @ T, np.eye(4), atol=1e-12)
    X = rng.normal(size=(10, 3))
    assert np.allclose(g.transform_points(g.invert_T(T), g.transform_points(T, X)), X)


def test_project_backproject_round_trip(rng):
    K = np.array([[500.0, 0, 320], [0, 510.0, 240], [0, 0, 1]])
    X = np.c_[rng.uniform(-1, 1, (100, 2)), rng.uniform(0.5, 5, 100)]
    uv, z = g.project(K, X)
    assert np.allclose(g.backproject(K, uv, z), X)


def test_depth_to_points_keeps_nan():
    K = np.array([[100.0, 0, 2], [0, 100.0, 1.5], [0, 0, 1]])
    depth = np.full((4, 5), 2.0, dtype=np.float32)
    depth[0, 0] = np.nan
    P = g.depth_to_points(K, depth)
    assert P.shape == (4, 5, 3)
    assert np.isnan(P[0, 0]).all()
    assert np.allclose(P[1:, 1:, 2], 2.0)


@pytest.mark.parametrize("with_scale", [True, False])
def test_umeyama_recovers_transform(rng, with_scale):
    s = 0.7 if with_scale else 1.0
    T = g.make_T(g.so3_exp(rng.normal(size=3)), rng.normal(size=3) * 3, s=s)
    X = rng.normal(size=(200, 3))
    Y = g.transform_points(T, X) + rng.normal(scale=1e-9, size=(200, 3))
    assert np.allclose(g.umeyama(X, Y, with_scale=with_scale), T, atol=1e-6)


def test_umeyama_rejects_bad_input():
    with pytest.raises(ValueError, match="at least 3"):
        g.umeyama(np.zeros((2, 3)), np.zeros((2, 3)), True)
    with pytest.raises(ValueError, match="equal shape"):
        g.umeyama(np.zeros((5, 3)), np.zeros((4, 3)), True)
