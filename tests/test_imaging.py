"""The one SSIM (gsslam.imaging): an independent numpy reference, known values, gradients, and the
metric (eval) and the loss (mapping) agreeing because both use it."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from gsslam.eval.image_metrics import ssim as eval_ssim
from gsslam.imaging import ssim, ssim_map
from gsslam.mapping import losses as L


def _reference_ssim_map(a: np.ndarray, b: np.ndarray) -> np.ndarray:  # [H, W, C] -> [H, W, C]
    """Direct 11 x 11 Gaussian-window sums (no separable filter), symmetric padding, float64."""
    x = np.arange(-5, 6)
    g = np.exp(-0.5 * (x / 1.5) ** 2)
    W = np.outer(g, g) / np.outer(g, g).sum()
    pa = np.pad(a, ((5, 5), (5, 5), (0, 0)), mode="symmetric")
    pb = np.pad(b, ((5, 5), (5, 5), (0, 0)), mode="symmetric")
    h, w, c = a.shape
    out = np.empty(a.shape)
    for i in range(h):
        for j in range(w):
            for k in range(c):
                wa, wb = pa[i : i + 11, j : j + 11, k], pb[i : i + 11, j : j + 11, k]
                ma, mb = (W * wa).sum(), (W * wb).sum()
                va, vb = (W * (wa - ma) ** 2).sum(), (W * (wb - mb) ** 2).sum()
                cab = (W * (wa - ma) * (wb - mb)).sum()
                c1, c2 = 0.01**2, 0.03**2
                out[i, j, k] = (2 * ma * mb + c1) * (2 * cab + c2) / ((ma**2 + mb**2 + c1) * (va + vb + c2))
    return out


def test_matches_a_direct_numpy_reference_including_the_border():
    rng = np.random.default_rng(0)
    a = rng.uniform(size=(17, 23, 3))
    b = np.clip(a + rng.normal(scale=0.1, size=a.shape), 0, 1)
    ref = _reference_ssim_map(a, b)
    got = ssim_map(torch.from_numpy(a), torch.from_numpy(b)).numpy()
    np.testing.assert_allclose(got, ref, atol=1e-12)
    assert ssim(torch.from_numpy(a), torch.from_numpy(b)).item() == pytest.approx(
        ref[5:-5, 5:-5].mean(), abs=1e-12
    )


def test_known_values():
    img = torch.rand(20, 30, 3, dtype=torch.float64)
    assert ssim(img, img).item() == pytest.approx(1.0, abs=1e-12)
    flat_a = torch.full((16, 16, 3), 0.3, dtype=torch.float64)
    flat_b = torch.full((16, 16, 3), 0.7, dtype=torch.float64)
    c1 = 0.01**2
    assert ssim(flat_a, flat_b).item() == pytest.approx((2 * 0.21 + c1) / (0.09 + 0.49 + c1), abs=1e-12)


def test_gradients_match_finite_differences():
    """Autograd against central differences along random directions (float64)."""
    rng = np.random.default_rng(1)
    a = torch.tensor(rng.uniform(size=(16, 18, 3)), requires_grad=True)
    b = torch.tensor(rng.uniform(size=(16, 18, 3)))
    ssim_map(a, b).mean().backward()
    h = 1e-6
    for _ in range(3):
        v = torch.tensor(rng.normal(size=a.shape))
        with torch.no_grad():
            fd = (ssim_map(a + h * v, b).mean() - ssim_map(a - h * v, b).mean()) / (2 * h)
        assert (a.grad * v).sum().item() == pytest.approx(fd.item(), rel=1e-6, abs=1e-9)


def test_loss_and_metric_use_the_same_ssim():
    rng = np.random.default_rng(2)
    a = rng.uniform(size=(40, 50, 3)).astype(np.float32)
    b = np.clip(a + rng.normal(scale=0.05, size=a.shape), 0, 1).astype(np.float32)
    ta, tb = torch.from_numpy(a), torch.from_numpy(b)
    assert ssim(ta, tb).item() == pytest.approx(eval_ssim(a, b), abs=1e-5)  # float32 vs float64
    expected = 0.8 * (ta - tb).abs().mean() + 0.2 * (1 - ssim_map(ta, tb)).mean()
    assert L.color_loss(ta, tb, 0.2).item() == pytest.approx(expected.item(), rel=1e-6)


@pytest.mark.parametrize(("dtype", "tol"), [(torch.float64, 1e-12), (torch.float32, 1e-5)])
def test_hand_written_gradient_equals_autograd(dtype, tol):
    """The render-only gradient (b fixed: the mapping loss) against autograd through the whole map
    (b requiring a gradient too takes that path); measured 1.1e-15 (float64) and 7.1e-7 (float32)
    relative at 120x160."""
    g = torch.Generator().manual_seed(3)
    a0 = torch.rand(37, 52, 3, generator=g, dtype=dtype)  # odd sizes: the borders' padding matters
    b = (a0 + 0.1 * torch.randn(37, 52, 3, generator=g, dtype=dtype)).clamp(0, 1)
    up = torch.rand(37, 52, 3, generator=g, dtype=dtype)
    grads, values = [], []
    for b_grad in (False, True):
        a = a0.clone().requires_grad_(True)
        s = ssim_map(a, b.clone().requires_grad_(b_grad))
        (s * up).sum().backward()
        grads.append(a.grad)
        values.append(s.detach())
    assert torch.equal(values[0], values[1])
    scale = float(grads[1].abs().max())
    assert scale > 0
    assert float((grads[0] - grads[1]).abs().max()) <= tol * scale
