"""Frustum culling before rasterization: the same images and gradients as rendering every Gaussian."""

from __future__ import annotations

import pytest
import torch
from test_rasterize_reference import intrinsics, small_pose

from gsslam.mapping import rasterize_cpu
from gsslam.mapping.projection import in_view, project_gaussians
from gsslam.mapping.rasterize import render

BACKENDS = ["torch"] + (["c"] if rasterize_cpu.available(torch.zeros(1)) else [])


def wide_scene(n: int, seed: int, dtype=torch.float64):
    """Gaussians all around the camera: in view, off the image's sides, straddling its border, behind."""
    g = torch.Generator().manual_seed(seed)
    means = (torch.rand(n, 3, generator=g, dtype=dtype) - 0.5) * torch.tensor([8.0, 6.0, 8.0], dtype=dtype)
    means[:, 2] += 2.5
    quats = torch.randn(n, 4, generator=g, dtype=dtype)
    # log-uniform scales, 1 cm .. 1 m, strongly anisotropic: wide Gaussians reach into the view from outside
    scales = torch.exp(torch.rand(n, 3, generator=g, dtype=dtype) * 4.6 - 4.6)
    opacities = torch.rand(n, generator=g, dtype=dtype) * 0.8 + 0.1
    colors = torch.rand(n, 3, generator=g, dtype=dtype)
    return means, quats, scales, opacities, colors


@pytest.mark.parametrize("seed", range(6))
def test_in_view_never_drops_a_visible_gaussian(seed):
    w, h = 40, 30
    means, quats, scales, _, _ = wide_scene(3000, seed)
    T, K = small_pose(seed), intrinsics(w, h)
    keep, centres, z = in_view(means, scales, T, K, w, h)
    proj = project_gaussians(means, quats, scales, T, K, w, h)
    visible = proj.radii > 0
    assert int(visible.sum()) > 500  # measured 1121-1273 of 3000 visible
    assert bool((keep | ~visible).all())  # conservative: every visible Gaussian is kept
    assert int(keep.sum()) < 0.65 * len(means)  # and it culls: measured 1564-1701 of 3000 kept
    torch.testing.assert_close(centres, proj.means2d.detach(), rtol=0, atol=0)
    torch.testing.assert_close(z, proj.depths.detach(), rtol=0, atol=0)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("seed", [0, 1])
def test_culled_render_equals_full_render_values_and_gradients(backend, seed):
    w, h = 32, 24
    scene = wide_scene(600, seed)
    T, K = small_pose(seed), intrinsics(w, h)
    bg = torch.tensor([0.2, 0.5, 0.7], dtype=torch.float64)
    weights = torch.rand(h, w, 8, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)
    results = []
    for cull in (False, True):
        inputs = [t.clone().requires_grad_(True) for t in (*scene, T)]
        out = render(*inputs, K, w, h, background=bg, backend=backend, cull=cull)
        img = torch.cat([out.color, out.depth[..., None], out.normal, out.alpha[..., None]], dim=-1)
        # a per-Gaussian term as the flow loss uses it: projected centres of the drawn Gaussians
        per_g = (out.means2d * (out.radii > 0)[:, None].to(out.means2d.dtype)).sum()
        ((img * weights).sum() + 1e-3 * per_g).backward()
        results.append((img.detach(), out, [t.grad for t in inputs]))
    (img_a, out_a, g_a), (img_b, out_b, g_b) = results
    assert float(out_a.alpha.detach().max()) > 0.9  # a non-trivial image
    assert 0 < int((out_a.radii > 0).sum()) < len(scene[0]) // 2  # some Gaussians culled
    assert torch.equal(out_a.radii, out_b.radii)
    torch.testing.assert_close(img_b, img_a, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(out_b.means2d, out_a.means2d, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(out_b.depths, out_a.depths, rtol=1e-12, atol=1e-12)
    names = ["means", "quats", "scales", "opacities", "colors", "T_cam_world"]
    for name, a, b in zip(names, g_b, g_a):
        assert float(b.abs().max()) > 0, f"gradient of {name} is zero: the test would be vacuous"
        torch.testing.assert_close(a, b, rtol=1e-10, atol=1e-10 * float(b.abs().max()), msg=name)


def test_nothing_in_view_renders_the_background():
    w, h = 16, 12
    means, quats, scales, opacities, colors = wide_scene(50, 3)
    means = means.clone()
    means[:, 2] = -5.0  # everything behind the camera
    T, K = torch.eye(4, dtype=torch.float64), intrinsics(w, h)
    bg = torch.tensor([0.1, 0.2, 0.3], dtype=torch.float64)
    out = render(means, quats, scales, opacities, colors, T, K, w, h, background=bg, cull=True)
    assert float(out.alpha.abs().max()) == 0.0
    torch.testing.assert_close(out.color, bg.expand(h, w, 3))
    assert int(out.radii.sum()) == 0 and out.means2d.shape == (50, 2)
