"""The gsplat (CUDA) backend against the pure-torch reference; skipped without CUDA or gsplat."""

from __future__ import annotations

import pytest
import torch
from test_rasterize_reference import intrinsics, random_scene, small_pose

from gsslam.mapping.projection import RasterizeError
from gsslam.mapping.rasterize import render


def test_gsplat_backend_on_cpu_tensors_raises_a_clear_error():
    scene = random_scene(4, 0, dtype=torch.float32)
    with pytest.raises(RasterizeError, match="cuda|CUDA"):
        render(*scene, torch.eye(4), intrinsics(8, 6, torch.float32), 8, 6, backend="gsplat")


@pytest.mark.gpu
def test_reference_runs_on_cuda_and_matches_cpu():
    w, h = 32, 24
    scene = random_scene(40, 0, dtype=torch.float32)
    T, K = small_pose(0, torch.float32), intrinsics(w, h, torch.float32)
    cpu = render(*scene, T, K, w, h, backend="torch")
    gpu = render(*(t.cuda() for t in scene), T.cuda(), K.cuda(), w, h, backend="torch")
    torch.testing.assert_close(gpu.color.cpu(), cpu.color, rtol=1e-4, atol=1e-4)


@pytest.mark.gpu
def test_gsplat_matches_reference_up_to_the_footprint_rule():
    pytest.importorskip("gsplat")
    w, h = 64, 48
    scene = [t.cuda() for t in random_scene(200, 1, dtype=torch.float32)]
    T, K = small_pose(1, torch.float32).cuda(), intrinsics(w, h, torch.float32).cuda()
    bg = torch.tensor([0.2, 0.2, 0.2], device="cuda")
    ref = render(*scene, T, K, w, h, background=bg, backend="torch")
    gs = render(*scene, T, K, w, h, background=bg, backend="gsplat")
    # gsplat decides footprints per 16x16 tile, we use the 3-sigma ellipse: tiny differences at fringes
    assert float((gs.color - ref.color).abs().mean()) < 5e-3
    assert float((gs.alpha - ref.alpha).abs().mean()) < 5e-3
    solid = (ref.alpha > 0.9) & (gs.alpha > 0.9)
    assert int(solid.sum()) > 100
    assert float((gs.depth - ref.depth)[solid].abs().median()) < 1e-2
    # gradients of the colour w.r.t. the means agree in direction
    means = scene[0].clone().requires_grad_(True)
    grads = []
    for backend in ("torch", "gsplat"):
        out = render(means, *scene[1:], T, K, w, h, background=bg, backend=backend)
        (g,) = torch.autograd.grad(out.color.sum(), means)
        grads.append(g.flatten())
    cos = torch.nn.functional.cosine_similarity(grads[0], grads[1], dim=0)
    assert float(cos) > 0.95
