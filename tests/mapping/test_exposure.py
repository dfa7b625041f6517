"""Per-keyframe exposure: a known gain and bias put on real frames is found again by the map's steps."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import torch

from gsslam.config import MapperConfig
from gsslam.geometry import invert_T, make_T, so3_exp
from gsslam.mapping import exposure as X
from gsslam.mapping.keyframes import make_keyframe
from gsslam.mapping.mapper import GaussianMapper
from gsslam.mapping.registration import register
from gsslam.mapping.state import render
from gsslam.types import Frame

CFG = MapperConfig(
    max_side=80, iterations=20, window=4, device="cpu", pose_refinement=False, lr_exposure=0.05,
    lambda_exposure=0.001,
)  # fmt: skip
GAIN, BIAS = 0.75, 0.06  # put on the second and fourth keyframe (the first is the gauge)


def test_apply_and_nearest():
    c = torch.rand(4, 5, 3)
    e = torch.tensor([[math.log(2.0)] * 3, [0.1, 0.0, -0.1]])
    assert torch.allclose(X.apply(c, e), 2 * c + torch.tensor([0.1, 0.0, -0.1]))
    assert X.apply(c, None) is c and torch.equal(X.apply(c, X.identity()), c)
    assert X.regularizer(X.identity()) == 0
    ex = {10: "a", 20: "b"}
    assert X.nearest_exposure(14, ex) == "a" and X.nearest_exposure(16, ex) == "b"
    assert X.nearest_exposure(15, ex) == "a" and X.nearest_exposure(3, {}) is None


def test_bias_is_premultiplied_and_unapply_inverts_apply():
    """A pixel the map does not cover (alpha 0) stays black whatever the exposure; a covered one gets
    the full affine change, and :func:`unapply` takes an observed image back to the map's exposure."""
    c = torch.rand(4, 5, 3) * 0.8
    alpha = torch.ones(4, 5)
    alpha[0] = 0.0
    e = torch.tensor([[math.log(0.8)] * 3, [0.05, 0.0, -0.02]])
    out = X.apply(c * alpha[..., None], e, alpha)
    assert torch.equal(out[0], torch.zeros(5, 3))
    assert torch.allclose(out[1:], 0.8 * c[1:] + e[1], atol=1e-6)
    assert torch.allclose(X.unapply(X.apply(c, e, torch.ones(4, 5)), e), c, atol=1e-6)
    assert X.unapply(c, None) is c


def test_exposed_fits_the_exposure_on_covered_pixels_against_a_fixed_render():
    """The map's loss sees the exposure held fixed; the exposure's own loss sees the render held fixed
    and only the pixels with alpha > 0.9 (a transparent, too dark render must not pass for a gain)."""
    torch.manual_seed(0)
    color = torch.rand(6, 7, 3, requires_grad=True)
    alpha = torch.full((6, 7), 0.95)
    alpha[:3] = 0.3  # the top half is barely covered
    image = torch.rand(6, 7, 3)
    e = X.identity().requires_grad_(True)
    shown, fit = X.exposed(color, alpha, e, image)
    shown.sum().backward()
    assert e.grad is None and color.grad is not None  # the map's render: exposure held fixed
    color.grad = None
    fit.backward()
    assert color.grad is None and e.grad is not None  # the exposure's fit: render held fixed
    image2 = image.clone()
    image2[:3] = 1.0 - image2[:3]  # change only the uncovered pixels: the fit must not notice
    e2 = X.identity().requires_grad_(True)
    _, fit2 = X.exposed(color, alpha, e2, image2)
    assert float(fit2.detach()) == float(fit.detach())
    assert X.exposed(color, alpha, None, image)[1] is None
    assert X.exposed(color, alpha, X.identity(), image)[1] is None  # not trained: no fit


def _two_keyframe_map(frames: list[Frame], cfg: MapperConfig, steps: int) -> GaussianMapper:
    m = GaussianMapper(cfg, frames[0].intrinsics)
    for f in frames:
        m.add_keyframe(f, f.T_world_cam_gt, 0)
    m.optimize(steps)
    return m


def _coverage(m: GaussianMapper, f: Frame) -> float:
    out = render(m.map, torch.as_tensor(invert_T(f.T_world_cam_gt), dtype=torch.float32))
    return float((out.alpha > 0.9).float().mean())


def test_exposure_does_not_thin_the_map(teddy_frames):
    """The two-keyframe map of the registration tests, with and without exposures: seen from the frame
    between the keyframes the map covers as much with them. Before the exposure was fitted on covered
    pixels only, it brightened the young map's too-dark render instead of its opacities growing:
    coverage 0.797 against 0.819 without (session 8); now 0.821."""
    f0, f1, f2 = teddy_frames[:3]
    cfg = MapperConfig(
        max_side=120, iterations=20, window=4, device="cpu", lambda_depth=0.5, feedback_min_age=0
    )  # fmt: skip
    off = _coverage(_two_keyframe_map([f0, f2], dataclasses.replace(cfg, exposure=False), 30), f1)
    on = _coverage(_two_keyframe_map([f0, f2], dataclasses.replace(cfg, exposure=True), 30), f1)
    assert on > off - 0.01, (on, off)


def test_registration_sees_a_new_frame_through_the_nearest_keyframe_s_exposure(teddy_frames):
    """Keyframes f0 (the gauge) and f2 with a darker exposure; frame 20, as dark as f2, is registered
    from a 2 cm / 1 degree error. Through the nearest keyframe's (f2's) exposure it is pulled towards its
    pose (measured 11.4 -> 5.9 px); compared with the map's own exposure (the identity) its colours
    differ by ~20 % and the registration is refused (measured: None)."""
    from mapping.test_mapper import _reprojection_px
    from mapping.test_registration import _graph_estimate

    f0, f2, f3 = teddy_frames[0], _exposed(teddy_frames[2]), _exposed(teddy_frames[3])
    cfg = MapperConfig(
        max_side=120, iterations=20, window=4, device="cpu", lambda_depth=0.5, feedback_min_age=0,
        exposure=True, lr_exposure=0.05, lambda_exposure=0.001,
    )  # fmt: skip
    m = _two_keyframe_map([f0, f2], cfg, 60)
    # measured log gain -0.154 (the truth, log 0.75, is -0.29: 60 steps find half of it)
    assert float(m.map.keyframes[f2.index].exposure[0].mean()) < -0.1
    T_bad = f3.T_world_cam_gt @ make_T(so3_exp(np.deg2rad([0.6, -0.5, 0.5])), [0.015, -0.01, 0.008])
    reg = m.register(f3, T_bad)
    assert reg is not None
    # measured 11.4 -> 5.9 px on the exposure branch, 8.6 px once the map step's float order changed (session
    # 8's C projection / SSIM gradient); 6.1 px after 90 steps; after 120 steps the pull is 0 (not
    # understood, docs/results.md "Exposure and the map's error, session 8"): the bound checks a pull
    assert _reprojection_px(f3, _graph_estimate(T_bad, reg)) < 0.85 * _reprojection_px(f3, T_bad)
    st = m.map
    kf = make_keyframe(cfg, f3, T_bad, -1, (st.intrinsics.width, st.intrinsics.height), st.device)
    plain = register(st, kf, cfg.registration_iterations)  # kf.exposure None: the map's own exposure
    assert plain is None or plain.residual > 1.2 * reg.residual


def _exposed(f: Frame) -> Frame:
    return dataclasses.replace(f, image=np.clip(GAIN * f.image + BIAS, 0.0, 1.0).astype(np.float32))


def _map(frames: list[Frame], exposure: bool) -> GaussianMapper:
    torch.manual_seed(0)
    m = GaussianMapper(dataclasses.replace(CFG, exposure=exposure), frames[0].intrinsics)
    for f in frames:
        m.add_keyframe(f, f.T_world_cam_gt, submap_id=0)
        m.optimize(40)
    m.finalize(iterations=120)
    return m


def _response(e: torch.Tensor) -> torch.Tensor:  # [2, 3] -> [9, 3]: the exposure at grey levels 0.1..0.9
    x = torch.linspace(0.1, 0.9, 9)[:, None]
    return torch.exp(e[0]) * x + e[1]


def test_exposure_recovers_a_known_gain_and_bias(teddy_frames):
    changed = {1, 3}
    frames = [_exposed(f) if k in changed else f for k, f in enumerate(teddy_frames)]
    m = _map(frames, exposure=True)
    assert m.map.keyframes[frames[0].index].exposure is None  # the gauge is never optimised
    truth = torch.linspace(0.1, 0.9, 9)[:, None] * GAIN + BIAS
    for k, f in enumerate(frames[1:], start=1):
        got = _response(m.map.keyframes[f.index].exposure)  # gain and bias trade off; the map they make
        want = truth if k in changed else torch.linspace(0.1, 0.9, 9)[:, None]
        # measured: 0.016 / 0.022 / 0.017 at most over the grey levels (session 7: 0.015 / 0.022 / 0.016);
        # the change to find is up to 0.165
        assert float((got - want).abs().max()) < 0.05, (k, got, want)
    poses = {f.index: f.T_world_cam_gt for f in frames}
    with_x = m.evaluate(iter(frames), poses)
    without = _map(frames, exposure=False).evaluate(iter(frames), poses)
    assert "exposure" in with_x and "exposure" not in without
    # measured: 27.88 vs 25.18 dB (session 7: 27.91): one colour per Gaussian cannot serve both exposures
    assert with_x["psnr_keyframes"] > without["psnr_keyframes"] + 1.5
