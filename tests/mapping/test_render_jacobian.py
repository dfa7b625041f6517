"""The pose Jacobian of a render from its warp (gsslam.mapping.render_jacobian): geometry and derivatives."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from gsslam.config import MapperConfig
from gsslam.mapping.pose import se3_delta_matrix
from gsslam.mapping.render_jacobian import front_depth, image_gradient, pixel_motion
from helpers.warp_columns import columns, planes_frames, two_keyframe_map


def _reproject(K, depth, delta):  # the pixels [H, W, 2] and depths [H, W] of the surface after the move
    H, W = depth.shape
    v, u = torch.meshgrid(
        torch.arange(H, dtype=torch.float64), torch.arange(W, dtype=torch.float64), indexing="ij"
    )
    X = (
        torch.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], torch.ones_like(u)], -1)
        * depth[..., None]
    )
    D = se3_delta_matrix(delta)  # T_world_cam' = T_world_cam @ D: camera points become D^-1 X
    Xn = (X - D[:3, 3]) @ D[:3, :3]  # = R^T (X - t), row-wise
    z = Xn[..., 2]
    return torch.stack([K[0, 0] * Xn[..., 0] / z + K[0, 2], K[1, 1] * Xn[..., 1] / z + K[1, 2]], -1), z


def test_pixel_motion_is_the_derivative_of_the_reprojection():
    """d u'/d delta and d Z'/d delta / Z against central differences of the exact reprojection, at a random
    depth map, away from delta = 0 in neither (the chart is the right perturbation at the current pose)."""
    rng = np.random.default_rng(0)
    K = torch.tensor([[90.0, 0, 61.0], [0, 95.0, 44.0], [0, 0, 1]], dtype=torch.float64)
    depth = torch.as_tensor(rng.uniform(0.5, 3.0, (9, 12)))
    motion, dz = pixel_motion(K, depth)  # [H, W, 2, 6], [H, W, 6]
    h = 1e-6
    for i in range(6):
        e = torch.zeros(6, dtype=torch.float64)
        e[i] = h
        (up, zp), (um, zm) = _reproject(K, depth, e), _reproject(K, depth, -e)
        assert torch.allclose(motion[..., i], (up - um) / (2 * h), rtol=1e-6, atol=1e-6)
        assert torch.allclose(dz[..., i], (zp - zm) / (2 * h) / depth, rtol=1e-6, atol=1e-8)
    # no depth: no motion
    motion0, dz0 = pixel_motion(K, torch.zeros(3, 4, dtype=torch.float64))
    assert not motion0.any() and not dz0.any()


def test_image_gradient_is_exact_on_cubics_and_one_sided_at_the_border():
    v, u = torch.meshgrid(
        torch.arange(7.0, dtype=torch.float64), torch.arange(9.0, dtype=torch.float64), indexing="ij"
    )
    img = torch.stack([u**3 - 2 * u * v, 3 * v**2, u + v], -1)  # [7, 9, 3]
    gu, gv = image_gradient(img)
    inner = (slice(2, -2), slice(2, -2))
    assert torch.allclose(gu[inner], torch.stack([3 * u**2 - 2 * v, 0 * u, 1 + 0 * u], -1)[inner])
    assert torch.allclose(gv[inner], torch.stack([-2 * u, 6 * v, 1 + 0 * u], -1)[inner])
    assert torch.allclose(gu[:, 0, 2], torch.ones(7, dtype=torch.float64))  # one-sided, exact on linears


def test_front_depth_is_the_nearest_depth_within_the_window():
    """An occluder (1 m, left) before a wall (3 m, right) with a blended column between (2 m) and an
    unrendered pixel: within 2 pixels of the occluder the occluder's depth, the wall's elsewhere."""
    depth = torch.full((7, 9), 3.0, dtype=torch.float64)
    depth[:, :3], depth[:, 3] = 1.0, 2.0
    depth[3, 8] = 0.0
    near = front_depth(depth, 5)
    one = torch.ones(7, dtype=torch.float64)
    for col, z in enumerate([1, 1, 1, 1, 1, 2, 3, 3]):  # the occluder is within 2 columns of 0-4
        assert torch.equal(near[:, col], z * one), (col, near[:, col])
    assert near[0, 8] == 3.0 and near[3, 8] == 0.0  # nothing rendered stays nothing
    assert torch.equal(front_depth(depth, 1), depth)


@pytest.fixture(scope="module")
def planes_map():
    cfg = MapperConfig(max_side=120, iterations=20, window=4, device="cpu", lambda_depth=0.5)
    cfg = dataclasses.replace(cfg, feedback_min_age=0)
    return two_keyframe_map(cfg, *planes_frames())


def test_warp_columns_match_central_differences_on_a_synthetic_occlusion(planes_map):
    """The ``planes`` scene (a panel 2.5 m before a wall at 4 m; a two-keyframe map, 120 px) at a pose
    between the keyframes: each warp column against central differences of renders. With the pixels
    moved by the nearest depth in the stencil's span (window 5) translation is no shorter than rotation;
    with the rendered (blended) depth (window 1) the log depth's translation columns were short."""
    st, kf = planes_map
    res = columns(st, kf, (1, 5))
    new, old = res[5], res[1]
    # measured (window 5): colour cos 0.973-0.989, gain 0.955-0.977 (rho) 0.939-0.950 (phi); log depth
    # cos 0.982-0.993, gain 0.951-0.996 (rho) 0.959-0.977 (phi); session 11's fresh environment (numpy
    # 2.4.6, opencv 4.14) trains a slightly different map: colour cos 0.956-0.989, gain 0.917-0.977
    assert (new["cos_c"] > 0.95).all() and (new["cos_d"] > 0.97).all(), new
    assert ((new["gain_c"] > 0.91) & (new["gain_c"] < 1.05)).all(), new["gain_c"]  # 0.917-0.977 (session 11)
    assert ((new["gain_d"] > 0.92) & (new["gain_d"] < 1.05)).all(), new["gain_d"]
    assert new["gain_c"][:3].min() > new["gain_c"][3:].min() - 0.02  # translation not shorter than rotation
    # window 1 (session 6): log depth's rho gains 0.790 0.846 0.918, colour's 0.920-0.934
    assert old["gain_d"][:2].max() < 0.88 and (new["gain_d"][:3] > old["gain_d"][:3] + 0.03).all()


def test_subpixel_slopes_bring_every_column_to_the_central_differences(planes_map):
    """The same with the render's exact slopes (two renders, principal point moved 0.1 px): the
    five-point slope's ~5 % shortfall (rotation above) is gone, translation and rotation alike."""
    st, kf = planes_map
    new = columns(st, kf, (5,), subpixel=True)[5]
    # measured: colour cos 0.977-0.993, gain 0.976-1.023; log depth cos 0.986-0.996, gain 0.979-1.028
    # (session 11's fresh environment, numpy 2.4.6 and opencv 4.14: colour cos 0.960-0.993)
    assert (new["cos_c"] > 0.955).all() and (new["cos_d"] > 0.98).all(), new
    assert (np.abs(new["gain_c"] - 1) < 0.05).all() and (np.abs(new["gain_d"] - 1) < 0.05).all(), new
