"""Mapping losses on hand-made inputs."""

from __future__ import annotations

import math

import pytest
import torch

from gsslam.imaging import ssim
from gsslam.mapping import losses as L

torch.manual_seed(0)


def test_identical_inputs_cost_nothing():
    img = torch.rand(24, 32, 3)
    depth = 1.0 + torch.rand(24, 32)
    assert L.color_loss(img, img, 0.2).item() == pytest.approx(0.0, abs=1e-6)
    assert ssim(img, img).item() == pytest.approx(1.0, abs=1e-5)
    assert L.inverse_depth_l1(depth, depth).item() == 0.0
    assert L.scale_invariant_depth(depth, depth).item() == pytest.approx(0.0, abs=1e-6)
    assert L.robust_flow_nll(torch.zeros(5, 2)).abs().max().item() < 1e-6


def test_known_values():
    a = torch.zeros(4, 4, 3)
    b = torch.full((4, 4, 3), 0.1)
    assert L.l1(a, b).item() == pytest.approx(0.1)
    assert L.psnr(a, b).item() == pytest.approx(20.0, abs=1e-4)
    d = torch.full((4, 4), 2.0)
    t = torch.full((4, 4), 4.0)
    assert L.inverse_depth_l1(d, t).item() == pytest.approx(0.25)
    # NaN target pixels are ignored
    t[0, 0] = float("nan")
    d[0, 0] = 100.0
    assert L.inverse_depth_l1(d, t).item() == pytest.approx(0.25)
    # isotropic scales: no regularization; one stretched axis: |s - mean|
    iso = torch.log(torch.full((3, 3), 0.5))
    assert L.scale_regularizer(iso).item() == pytest.approx(0.0, abs=1e-7)
    stretched = torch.log(torch.tensor([[3.0, 0.0 + 1e-30, 0.0 + 1e-30]]))
    assert L.scale_regularizer(stretched).item() == pytest.approx((2 + 1 + 1) / 3, rel=1e-5)


def test_scale_invariant_depth_ignores_global_scale():
    d = 1.0 + torch.rand(16, 16)
    assert L.scale_invariant_depth(3.7 * d, d).item() == pytest.approx(0.0, abs=1e-6)
    assert L.scale_invariant_depth(d + torch.rand(16, 16), d).item() > 0.05


def test_depth_normal_consistency_on_a_plane():
    K = torch.tensor([[50.0, 0, 16], [0, 50.0, 12], [0, 0, 1]])
    v, u = torch.meshgrid(torch.arange(24.0), torch.arange(32.0), indexing="ij")
    # plane z = 2 + 0.5 x  (x = (u - cx) / fx * z)  ->  z = 2 / (1 - 0.5 (u - cx) / fx)
    z = 2.0 / (1.0 - 0.5 * (u - 16) / 50.0)
    n_true = torch.tensor([0.5, 0.0, -1.0]) / math.sqrt(1.25)
    nd = L.normals_from_depth(z, K)
    assert torch.allclose(nd[5:-5, 5:-5], n_true.expand(14, 22, 3), atol=1e-4)
    good = L.depth_normal_consistency(z, n_true.expand(24, 32, 3) * 0.7, K)  # scale of n ignored
    bad = L.depth_normal_consistency(z, torch.tensor([0.0, 0.0, -1.0]).expand(24, 32, 3), K)
    assert good.item() < 1e-4
    assert bad.item() == pytest.approx(1 - 1 / math.sqrt(1.25), abs=1e-3)


def test_robust_flow_nll_saturates_for_outliers():
    r = torch.tensor([[0.0, 0.0], [1.0, 0.0], [3.0, 0.0], [50.0, 0.0], [500.0, 0.0]], requires_grad=True)
    nll = L.robust_flow_nll(r, sigma=1.0, inlier_prior=0.9, outlier_range=20.0)
    assert torch.all(nll[1:] > nll[:-1] - 1e-6)  # monotone
    assert nll[1].item() == pytest.approx(0.5, abs=0.01)  # ~ r^2 / 2 sigma^2 for inliers
    cap = math.log((0.9 / (2 * math.pi) + 0.1 / 400) * 400 / 0.1)
    assert nll[3].item() == pytest.approx(cap, rel=1e-4)
    assert nll[4].item() == pytest.approx(cap, rel=1e-6)
    nll.sum().backward()
    assert abs(r.grad[4, 0].item()) < 1e-9  # outliers stop pulling
    assert r.grad[1, 0].item() > 0.5


def test_flow_loss_zero_for_consistent_motion_and_normalized_error():
    h, w = 20, 30
    flow = torch.zeros(h, w, 2)
    flow[..., 0] = 3.0
    flow[..., 1] = -1.0
    valid = torch.ones(h, w, dtype=torch.bool)
    valid[:, :5] = False
    uv_a = torch.tensor([[10.0, 10.0], [20.2, 5.7], [2.0, 3.0], [-4.0, 3.0]])
    uv_b = uv_a + torch.tensor([3.0, -1.0])
    loss, err, usable = L.flow_loss(uv_a, uv_b, flow, valid)
    assert loss.item() == pytest.approx(0.0, abs=1e-6)
    assert usable.tolist() == [True, True, False, False]  # invalid flow pixel, outside the image
    assert torch.allclose(err[:2], torch.zeros(2), atol=1e-6)
    assert torch.isnan(err[2:]).all()
    # residual equal to the motion itself: normalized error |r| / (|f| + 1)
    loss2, err2, _ = L.flow_loss(uv_a, uv_a.clone(), flow, valid)
    assert loss2.item() > 0
    assert err2[0].item() == pytest.approx(math.sqrt(10) / (math.sqrt(10) + 1), rel=1e-5)
    # the normalized error does not depend on the image scale
    e_small = L.normalized_flow_error(torch.tensor([[1.0, 0.0]]), torch.tensor([[10.0, 0.0]]), eps_px=0.0)
    e_big = L.normalized_flow_error(torch.tensor([[4.0, 0.0]]), torch.tensor([[40.0, 0.0]]), eps_px=0.0)
    assert e_small.item() == pytest.approx(e_big.item())


def test_inverse_depth_l1_unit_makes_it_scale_free_and_weight_scales_pixels():
    d = torch.tensor([[1.0, 2.0], [4.0, 1.0]])
    t = torch.tensor([[2.0, 2.0], [2.0, float("nan")]])
    base = L.inverse_depth_l1(d, t, unit=2.0)
    # the same scene in units 10x larger, with the unit (e.g. the median depth) scaled along: same value
    assert L.inverse_depth_l1(10 * d, 10 * t, unit=20.0).item() == pytest.approx(base.item())
    w = torch.tensor([[0.5, 1.0], [0.0, 1.0]])
    # residuals 0.5, 0, 0.25 (x unit 2) weighted 0.5, 1, 0, averaged over the 3 valid pixels
    assert L.inverse_depth_l1(d, t, weight=w, unit=2.0).item() == pytest.approx(2 * 0.25 / 3)
