"""The pure-torch reference rasterizer against a per-pixel loop, gradcheck and geometric sanity."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from gsslam.mapping.projection import RasterizeError, quat_to_rotmat
from gsslam.mapping.rasterize import render


def random_scene(n: int, seed: int, dtype=torch.float64, z0: float = 3.0):
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=g, dtype=dtype) * torch.tensor([0.6, 0.4, 0.5], dtype=dtype)
    means[:, 2] += z0
    quats = torch.randn(n, 4, generator=g, dtype=dtype)
    scales = torch.rand(n, 3, generator=g, dtype=dtype) * 0.25 + 0.05
    opacities = torch.rand(n, generator=g, dtype=dtype) * 0.8 + 0.1
    colors = torch.rand(n, 3, generator=g, dtype=dtype)
    return means, quats, scales, opacities, colors


def small_pose(seed: int, dtype=torch.float64) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    w = torch.randn(3, generator=g, dtype=dtype) * 0.05
    W = torch.zeros(3, 3, dtype=dtype)
    W[0, 1], W[0, 2], W[1, 2] = -w[2], w[1], -w[0]
    W = W - W.T
    T = torch.eye(4, dtype=dtype)
    T[:3, :3] = torch.linalg.matrix_exp(W)
    T[:3, 3] = torch.randn(3, generator=g, dtype=dtype) * 0.05
    return T


def intrinsics(width: int, height: int, dtype=torch.float64) -> torch.Tensor:
    f = 1.2 * width
    return torch.tensor([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1]], dtype=dtype)


def loop_render(means, quats, scales, opacities, colors, T, K, width, height, bg):
    """Independent numpy per-pixel loop of the documented rules (no clamping of x/z needed here)."""
    means, quats, scales = means.numpy(), quats.numpy(), scales.numpy()
    opacities, colors, T, K = opacities.numpy(), colors.numpy(), T.numpy(), K.numpy()
    R_g = quat_to_rotmat(torch.from_numpy(quats)).numpy()
    p = means @ T[:3, :3].T + T[:3, 3]
    order = np.argsort(p[:, 2], kind="stable")
    mu, inv = [], []
    for i in range(len(means)):
        x, y, z = p[i]
        J = np.array([[K[0, 0] / z, 0, -K[0, 0] * x / z**2], [0, K[1, 1] / z, -K[1, 1] * y / z**2]])
        S = R_g[i] @ np.diag(scales[i] ** 2) @ R_g[i].T
        cov = J @ T[:3, :3] @ S @ T[:3, :3].T @ J.T + 0.3 * np.eye(2)
        mu.append([K[0, 0] * x / z + K[0, 2], K[1, 1] * y / z + K[1, 2]])
        inv.append(np.linalg.inv(cov))
    color = np.zeros((height, width, 3))
    depth = np.zeros((height, width))
    alpha = np.zeros((height, width))
    for v in range(height):
        for u in range(width):
            Tr, c, d = 1.0, np.zeros(3), 0.0
            for i in order:
                if p[i, 2] <= 0.01:
                    continue
                dd = np.array([u, v]) - mu[i]
                power = 0.5 * dd @ inv[i] @ dd
                a = min(0.99, opacities[i] * math.exp(-power))
                if power > 4.5 or a < 1 / 255:
                    continue
                if Tr * (1 - a) < 1e-4:
                    break
                c += a * Tr * colors[i]
                d += a * Tr * p[i, 2]
                Tr *= 1 - a
            color[v, u] = c + Tr * bg.numpy()
            alpha[v, u] = 1 - Tr
            depth[v, u] = d / (1 - Tr) if 1 - Tr > 1e-6 else 0.0
    return color, depth, alpha


@pytest.mark.parametrize("seed", [0, 1])
def test_reference_matches_per_pixel_loop(seed):
    w, h = 16, 12
    scene = random_scene(5, seed)
    T, K = small_pose(seed), intrinsics(w, h)
    bg = torch.tensor([0.2, 0.3, 0.4], dtype=torch.float64)
    out = render(*scene, T, K, w, h, background=bg, backend="torch")
    color, depth, alpha = loop_render(*scene, T, K, w, h, bg)
    assert alpha.max() > 0.5  # the scene is actually visible
    np.testing.assert_allclose(out.color.numpy(), color, atol=1e-10)
    np.testing.assert_allclose(out.alpha.numpy(), alpha, atol=1e-10)
    np.testing.assert_allclose(out.depth.numpy(), depth, atol=1e-8)


def test_reference_gradcheck_all_inputs_and_pose():
    w, h = 8, 6
    scene = random_scene(3, seed=3, z0=2.0)
    T, K = small_pose(3), intrinsics(w, h)
    bg = torch.tensor([0.1, 0.5, 0.9], dtype=torch.float64)
    weights = torch.rand(h, w, 8, generator=torch.Generator().manual_seed(0), dtype=torch.float64)

    def f(means, quats, scales, opacities, colors, T):
        out = render(means, quats, scales, opacities, colors, T, K, w, h, background=bg, backend="torch")
        img = torch.cat([out.color, out.depth[..., None], out.normal, out.alpha[..., None]], dim=-1)
        return (img * weights).sum()

    inputs = tuple(t.clone().requires_grad_(True) for t in (*scene, T))
    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-5, rtol=1e-4)


def test_plane_facing_camera_gives_its_depth_and_normal():
    w, h = 20, 16
    dt = torch.float64
    means = torch.tensor([[0.1, -0.05, 2.5]], dtype=dt)
    quats = torch.tensor([[1.0, 0.0, 0.0, 0.0]], dtype=dt)
    scales = torch.tensor([[2.0, 2.0, 1e-3]], dtype=dt)  # a thin disc in the z = 2.5 plane
    out = render(
        means,
        quats,
        scales,
        torch.tensor([0.95], dtype=dt),
        torch.ones(1, 3, dtype=dt),
        torch.eye(4, dtype=dt),
        intrinsics(w, h),
        w,
        h,
        backend="torch",
    )
    covered = out.alpha > 0.5
    assert covered.all()
    np.testing.assert_allclose(out.depth[covered].numpy(), 2.5, atol=1e-9)
    n = out.normal[covered] / out.alpha[covered][:, None]
    np.testing.assert_allclose(n.numpy(), np.tile([0.0, 0.0, -1.0], (int(covered.sum()), 1)), atol=1e-9)
    assert int(out.radii[0]) > 0


def test_gaussians_behind_or_too_near_the_camera_are_culled():
    w, h = 16, 12
    dt = torch.float64
    means = torch.tensor([[0.0, 0.0, -2.0], [0.0, 0.0, 0.005], [0.0, 0.0, 2.0]], dtype=dt)
    quats = torch.tensor([[1.0, 0.0, 0.0, 0.0]] * 3, dtype=dt)
    scales = torch.full((3, 3), 0.3, dtype=dt)
    colors = torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], dtype=dt)
    out = render(
        means,
        quats,
        scales,
        torch.full((3,), 0.9, dtype=dt),
        colors,
        torch.eye(4, dtype=dt),
        intrinsics(w, h),
        w,
        h,
        near=0.01,
        backend="torch",
    )
    assert out.radii.tolist()[:2] == [0, 0] and int(out.radii[2]) > 0
    assert float(out.color[..., :2].abs().max()) == 0.0  # neither red nor green appears
    assert float(out.color[..., 2].max()) > 0.5
    # moving the camera behind the last Gaussian leaves an empty image
    T = torch.eye(4, dtype=dt)
    T[2, 3] = -5.0
    out = render(
        means,
        quats,
        scales,
        torch.full((3,), 0.9, dtype=dt),
        colors,
        T,
        intrinsics(w, h),
        w,
        h,
        backend="torch",
    )
    assert int(out.radii.max()) == 0 and float(out.alpha.max()) == 0.0


def test_bad_shapes_raise_a_clear_error():
    scene = random_scene(4, 0)
    with pytest.raises(RasterizeError, match="quats"):
        render(
            scene[0],
            scene[1][:, :3],
            *scene[2:],
            torch.eye(4, dtype=torch.float64),
            intrinsics(8, 6),
            8,
            6,
            backend="torch",
        )
    with pytest.raises(RasterizeError, match="backend"):
        render(*scene, torch.eye(4, dtype=torch.float64), intrinsics(8, 6), 8, 6, backend="nope")
