"""Submap-level errors (gsslam.eval.submaps): the best submap pose, a loop's reference, pose differences."""

import numpy as np
import pytest

from gsslam.eval import EvalError
from gsslam.eval.submaps import best_submap_pose, loop_reference, pose_difference
from gsslam.geometry import invert_T, make_T


def random_rigid(rng, trans=1.0, angle=1.0):
    w = rng.normal(size=3)
    w *= angle / np.linalg.norm(w)
    K = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    th = np.linalg.norm(w)
    R = np.eye(3) + np.sin(th) / th * K + (1 - np.cos(th)) / th**2 * K @ K
    return make_T(R, rng.normal(scale=trans, size=3))


def submap(rng, views=6):
    """Local keyframe poses along a short arc (the first at the origin), as an encoder gives them."""
    L = [np.eye(4)] + [random_rigid(rng, trans=0.05, angle=0.1) for _ in range(views - 1)]
    return np.stack(L)


def test_best_submap_pose_recovers_the_true_frame_under_any_world_transform():
    rng = np.random.default_rng(0)
    L = submap(rng)
    S = random_rigid(rng, trans=2.0, angle=2.5)  # far from identity
    G = np.stack([S @ T for T in L])  # exact ground truth for these local poses
    assert np.allclose(best_submap_pose(L, G), S, atol=1e-9)
    W = random_rigid(rng, trans=3.0, angle=1.0)  # another world frame for the ground truth
    assert np.allclose(best_submap_pose(L, np.stack([W @ g for g in G])), W @ S, atol=1e-9)


def test_best_submap_pose_is_no_farther_from_ground_truth_than_the_anchor_frame():
    # local poses with errors: the fit over all keyframes beats placing the submap by its first view
    rng = np.random.default_rng(1)
    L = submap(rng, views=7)
    S = random_rigid(rng, trans=1.0, angle=0.7)
    noisy = np.stack([L[0]] + [T @ random_rigid(rng, trans=0.004, angle=0.004) for T in L[1:]])
    G = np.stack([S @ T for T in L])
    G[0] = G[0] @ random_rigid(rng, trans=0.006, angle=0.006)  # the anchor's ground truth is off too

    def dist(Sw):
        return np.sqrt(np.mean([np.sum(((Sw @ T)[:3, 3] - g[:3, 3]) ** 2) for T, g in zip(noisy, G)]))

    best = best_submap_pose(noisy, G)
    anchor = G[0] @ invert_T(noisy[0])
    assert dist(best) < dist(anchor)


def test_loop_reference_and_pose_difference():
    rng = np.random.default_rng(2)
    Si, Sm = random_rigid(rng), random_rigid(rng)
    T_i_m = loop_reference(Si, Sm)
    X_m = rng.normal(size=(10, 3))
    X_world = X_m @ Sm[:3, :3].T + Sm[:3, 3]
    assert np.allclose(X_m @ T_i_m[:3, :3].T + T_i_m[:3, 3], (X_world - Si[:3, 3]) @ Si[:3, :3])
    assert pose_difference(T_i_m, T_i_m) == pytest.approx((0.0, 0.0), abs=1e-6)
    D = make_T(np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]]), np.array([0.003, 0.0, 0.004]))  # 90 deg, 5 mm
    t, r = pose_difference(T_i_m @ D, T_i_m)
    assert t == pytest.approx(0.005) and r == pytest.approx(90.0)


def test_best_submap_pose_refuses_mismatched_inputs():
    with pytest.raises(EvalError):
        best_submap_pose(np.zeros((3, 4, 4)), np.zeros((2, 4, 4)))
