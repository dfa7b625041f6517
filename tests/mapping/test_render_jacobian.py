"""The pose Jacobian of a render from its warp (gsslam.mapping.render_jacobian): geometry and derivatives."""

from __future__ import annotations

import numpy as np
import torch

from gsslam.mapping.pose import se3_delta_matrix
from gsslam.mapping.render_jacobian import image_gradient, pixel_motion


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
