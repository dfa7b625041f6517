"""The compiled CPU compositor against the pure-torch reference: values and gradients."""

from __future__ import annotations

import pytest
import torch
from test_rasterize_reference import intrinsics, random_scene, small_pose

from gsslam.mapping import rasterize, rasterize_cpu
from gsslam.mapping.rasterize import RasterizerUnavailableError, render

pytestmark = pytest.mark.skipif(
    not rasterize_cpu.available(torch.zeros(1)), reason="no compiled C kernel (no C compiler)"
)


def _render_and_grads(backend, scene, T, K, w, h, bg, weights, low_pass=0.3):
    inputs = [t.clone().requires_grad_(True) for t in (*scene, T)]
    out = render(*inputs, K, w, h, background=bg, backend=backend, low_pass=low_pass)
    img = torch.cat([out.color, out.depth[..., None], out.normal, out.alpha[..., None]], dim=-1)
    (img * weights).sum().backward()
    return img.detach(), out, [t.grad for t in inputs]


@pytest.mark.parametrize(("dtype", "rtol"), [(torch.float64, 1e-10), (torch.float32, 2e-4)])
@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("low_pass", [0.3, 4.8])  # 4.8: the dilation of a 4x zoomed render
def test_fast_matches_reference_values_and_gradients(dtype, rtol, seed, low_pass):
    w, h = 32, 24
    scene = random_scene(40, seed, dtype=dtype)
    T, K = small_pose(seed, dtype=dtype), intrinsics(w, h, dtype=dtype)
    bg = torch.tensor([0.3, 0.6, 0.1], dtype=dtype)
    weights = torch.rand(h, w, 8, generator=torch.Generator().manual_seed(seed), dtype=dtype)
    img_ref, out_ref, g_ref = _render_and_grads("torch", scene, T, K, w, h, bg, weights, low_pass)
    img_fast, out_fast, g_fast = _render_and_grads("c", scene, T, K, w, h, bg, weights, low_pass)
    assert (
        float(out_ref.alpha.detach().max()) > 0.9 and float(out_ref.alpha.detach().min()) < 0.1
    )  # a non-trivial image
    assert torch.equal(out_ref.radii, out_fast.radii)
    torch.testing.assert_close(img_fast, img_ref, rtol=rtol, atol=rtol)
    names = ["means", "quats", "scales", "opacities", "colors", "T_cam_world"]
    for name, a, b in zip(names, g_fast, g_ref):
        assert float(b.abs().max()) > 0, f"reference gradient of {name} is zero: the test would be vacuous"
        scale = float(b.abs().max())
        torch.testing.assert_close(a, b, rtol=rtol, atol=rtol * scale, msg=lambda m, n=name: f"{n}: {m}")


def test_fast_gradcheck_float64():
    w, h = 10, 8
    scene = random_scene(4, seed=7, z0=2.0)
    T, K = small_pose(7), intrinsics(w, h)
    weights = torch.rand(h, w, 8, generator=torch.Generator().manual_seed(1), dtype=torch.float64)

    def f(means, quats, scales, opacities, colors, T):
        out = render(means, quats, scales, opacities, colors, T, K, w, h, backend="c")
        img = torch.cat([out.color, out.depth[..., None], out.normal, out.alpha[..., None]], dim=-1)
        return (img * weights).sum()

    inputs = tuple(t.clone().requires_grad_(True) for t in (*scene, T))
    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-5, rtol=1e-4)


def test_fast_handles_empty_and_saturated_images():
    w, h = 16, 12
    dt = torch.float32
    K = intrinsics(w, h, dtype=dt)
    # every Gaussian behind the camera: nothing drawn, zero gradients, no crash
    scene = list(random_scene(10, 0, dtype=dt))
    scene[0] = scene[0] * torch.tensor([1.0, 1.0, -1.0])
    _, out, grads = _render_and_grads(
        "c", scene, torch.eye(4, dtype=dt), K, w, h, None, torch.ones(h, w, 8, dtype=dt)
    )
    assert float(out.alpha.detach().max()) == 0.0 and all(float(g.abs().max()) == 0.0 for g in grads)
    # many opaque layers: transmittance early stop engaged, still equal to the reference
    scene = list(random_scene(60, 1, dtype=dt))
    scene[2] = scene[2] * 4.0
    scene[3] = torch.full_like(scene[3], 0.98)
    a = render(*scene, torch.eye(4, dtype=dt), K, w, h, backend="c")
    b = render(*scene, torch.eye(4, dtype=dt), K, w, h, backend="torch")
    assert float(a.alpha.min()) > 0.99
    torch.testing.assert_close(a.color, b.color, rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(a.depth, b.depth, rtol=1e-4, atol=1e-4)


def _reset_loader(monkeypatch):
    monkeypatch.setattr(rasterize_cpu, "_lib", None)
    monkeypatch.setattr(rasterize_cpu, "_origin", None)
    monkeypatch.setattr(rasterize_cpu, "_failure", None)
    monkeypatch.setattr(rasterize_cpu, "_installed_library", lambda: None)  # as in a checkout never built


def test_without_a_compiler_auto_falls_back_to_the_reference_and_c_raises(monkeypatch, tmp_path, caplog):
    _reset_loader(monkeypatch)
    monkeypatch.setattr(rasterize, "_warned", False)
    monkeypatch.setattr(rasterize_cpu, "_compiler", lambda: None)
    monkeypatch.setenv("GSSLAM_CACHE_DIR", str(tmp_path))  # empty cache: a build would be needed
    w, h = 16, 12
    scene = random_scene(10, 4)
    T, K = small_pose(4), intrinsics(w, h)
    out = render(*scene, T, K, w, h, backend="auto")
    render(*scene, T, K, w, h, backend="auto")
    assert not rasterize_cpu.available(scene[0])
    warnings = [r for r in caplog.records if r.levelname == "WARNING"]
    assert len(warnings) == 1 and "pure-torch reference" in warnings[0].getMessage()
    ref = render(*scene, T, K, w, h, backend="torch")
    torch.testing.assert_close(out.color, ref.color, rtol=0, atol=0)
    with pytest.raises(RasterizerUnavailableError, match="no C compiler"):
        render(*scene, T, K, w, h, backend="c")


def test_kernel_builds_into_a_fresh_cache(monkeypatch, tmp_path):
    _reset_loader(monkeypatch)
    monkeypatch.setenv("GSSLAM_CACHE_DIR", str(tmp_path))
    assert rasterize_cpu.available(torch.zeros(1)) and rasterize_cpu.origin() == "built"
    assert len(list(tmp_path.glob("rasterize_cpu_*.so"))) == 1


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("threads", [1, 2])
def test_reused_spans_and_falloffs_give_the_plain_kernels_results_bit_for_bit(dtype, threads):
    """``reuse`` (the fill reads the count pass's row spans, the backward the fill's exp(-power)) is
    the same arithmetic in the same order as the kernels before session 8: equal values and gradients."""
    from gsslam.mapping.projection import project_gaussians
    from gsslam.mapping.rasterize_cpu import composite_cpu

    w, h = 64, 48
    means, quats, scales, opacities, colors = random_scene(1500, seed=3, dtype=dtype)
    scales = scales * 0.5
    T, K = small_pose(3, dtype=dtype), intrinsics(w, h, dtype=dtype)
    with torch.no_grad():
        p = project_gaussians(means, quats, scales, T, K, w, h)
    feat = torch.cat([colors, p.depths[:, None], p.normals], dim=-1)
    g = torch.Generator().manual_seed(5)
    g_feat = torch.rand(h, w, 7, generator=g, dtype=dtype)
    g_alpha = torch.rand(h, w, generator=g, dtype=dtype)
    results = {}
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        for reuse in (True, False):
            ins = [t.detach().clone().requires_grad_(True) for t in (p.means2d, p.conics, opacities, feat)]
            out, alpha = composite_cpu(*ins, p.depths, p.radii, w, h, reuse=reuse)
            ((out * g_feat).sum() + (alpha * g_alpha).sum()).backward()
            results[reuse] = [out.detach(), alpha.detach()] + [t.grad for t in ins]
    finally:
        torch.set_num_threads(before)
    assert float(results[True][1].max()) > 0.999  # opaque pixels: the early stop is exercised
    for a, b in zip(results[True], results[False]):
        assert float(b.abs().max()) > 0
        assert torch.equal(a, b)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_compositor_threads_give_the_same_image_and_gradients_up_to_summation_order(dtype):
    """``compositor_threads(n)`` runs the passes on n row bands whatever torch's thread count; bands hold
    about equal pairs (here most of them in the lower half of the view). The image is bit for bit the
    one-band image (each pixel is one band's); gradients are summed per band, then across bands."""
    from gsslam.mapping.projection import project_gaussians
    from gsslam.mapping.rasterize_cpu import band_threads, composite_cpu, compositor_threads

    w, h = 64, 48
    means, quats, scales, opacities, colors = random_scene(1500, seed=4, dtype=dtype)
    T, K = small_pose(3, dtype=dtype), intrinsics(w, h, dtype=dtype)
    with torch.no_grad():
        p = project_gaussians(means, quats, scales * 0.5, T, K, w, h)
    radii = torch.where(p.means2d[:, 1] > 0.4 * h, p.radii, p.radii * (torch.arange(len(p.radii)) % 4 == 0))
    feat = torch.cat([colors, p.depths[:, None], p.normals], dim=-1)
    g = torch.Generator().manual_seed(6)
    g_feat = torch.rand(h, w, 7, generator=g, dtype=dtype)
    g_alpha = torch.rand(h, w, generator=g, dtype=dtype)
    results = {}
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        for n in (1, 2, 3):
            with compositor_threads(n):
                assert band_threads() == n
                leaves = (p.means2d, p.conics, opacities, feat)
                ins = [t.detach().clone().requires_grad_(True) for t in leaves]
                out, alpha = composite_cpu(*ins, p.depths, radii, w, h)
                ((out * g_feat).sum() + (alpha * g_alpha).sum()).backward()
            results[n] = [out.detach(), alpha.detach()] + [t.grad for t in ins]
        assert band_threads() == 1  # torch's again outside the block
    finally:
        torch.set_num_threads(before)
    tol = 1e-12 if dtype == torch.float64 else 1e-5
    for n in (2, 3):
        assert torch.equal(results[n][0], results[1][0]) and torch.equal(results[n][1], results[1][1])
        for a, b in zip(results[n][2:], results[1][2:]):
            assert float(b.abs().max()) > 0
            torch.testing.assert_close(a, b, rtol=tol, atol=tol * float(b.abs().max()))
