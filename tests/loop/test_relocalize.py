"""Re-localization across chains: ICP refinement recovers a known rigid transform; dense points of a
submap come out in its local frame, one per voxel."""

from __future__ import annotations

import numpy as np

from gsslam.geometry import make_T, so3_exp, transform_points
from gsslam.loop.relocalize import local_points, refine_rigid
from gsslam.types import CameraIntrinsics, SubmapEncoding
from helpers.loop_scenes import corner_points


def _corner(rng) -> np.ndarray:  # [n, 3]
    return corner_points(rng, relief=0.02, wave=7)


def test_icp_recovers_a_perturbed_rigid_transform():
    rng = np.random.default_rng(0)
    P = _corner(rng)
    T_true = make_T(so3_exp(np.array([0.1, -0.2, 0.15])), np.array([0.3, -0.1, 0.2]))
    Q = transform_points(np.linalg.inv(T_true), P)  # Q in the other frame: P = T_true Q
    T0 = make_T(so3_exp(np.array([0.02, 0.01, -0.02])), np.array([0.02, -0.015, 0.01])) @ T_true
    T, fitness = refine_rigid(T0, P, Q, max_distance=0.05)
    assert fitness > 0.9
    assert np.abs(T - T_true).max() < 2e-3
    assert np.abs(T0 - T_true).max() > 1e-2  # the start was really off


def test_local_points_are_in_the_submap_frame_and_voxelized():
    K = CameraIntrinsics(50.0, 50.0, 15.5, 11.5, 32, 24)
    u, v = np.meshgrid(np.arange(32), np.arange(24))
    z = np.full((24, 32), 2.0)
    pts_cam = np.stack([(u - K.cx) / K.fx * z, (v - K.cy) / K.fy * z, z], axis=-1)
    pts_cam[0, 0] = np.nan  # unknown
    T1 = make_T(np.eye(3), np.array([1.013, 0.0, 0.0]))  # no point of view 1 falls on one of view 0
    enc = SubmapEncoding(
        [0, 1], np.stack([np.eye(4), T1]), np.stack([pts_cam, pts_cam]), np.ones((2, 24, 32)), K
    )
    dense = local_points(enc, voxel=1e-6)
    assert len(dense) == 2 * (24 * 32 - 1)
    np.testing.assert_allclose(np.sort(dense[:, 2])[[0, -1]], [2.0, 2.0])
    assert dense[:, 0].max() > 1.5  # the second view's points moved by T1
    coarse = local_points(enc, voxel=0.5)
    assert 0 < len(coarse) < 40
