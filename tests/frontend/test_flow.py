"""Flow estimators on a real TUM image with a known synthetic shift; forward-backward checks."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from gsslam.config import FlowConfig
from gsslam.frontend.flow import (
    FlowError,
    compose_flows,
    forward_backward_mask,
    make_flow_estimator,
    register_flow_method,
    resize_flow,
)
from helpers.tum import load_tum


def _shift(img: np.ndarray, dx: float, dy: float) -> np.ndarray:
    M = np.array([[1.0, 0.0, dx], [0.0, 1.0, dy]])
    return cv2.warpAffine(
        img, M, (img.shape[1], img.shape[0]), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT
    )


@pytest.fixture(scope="module")
def teddy(bundled_tum):
    return load_tum(bundled_tum, [10, 14])


@pytest.mark.parametrize(
    "method,preset,bound",
    [("dis", "medium", 0.3), ("dis", "fast", 0.3), ("dis", "ultrafast", 0.3), ("farneback", "medium", 0.3)],
)
def test_flow_recovers_subpixel_shift(teddy, method, preset, bound):
    img0 = teddy[0].image
    dx, dy = 3.4, -2.3
    img1 = _shift(img0, dx, dy)
    flow = make_flow_estimator(FlowConfig(method=method, dis_preset=preset))(img0, img1)
    assert flow.shape == img0.shape[:2] + (2,)
    inner = flow[40:-40, 40:-40].reshape(-1, 2)
    err = np.linalg.norm(inner - [dx, dy], axis=1)
    assert np.median(err) < bound, np.median(err)


def test_flow_is_upscaled_to_full_resolution_pixels(teddy):
    img0 = teddy[0].image
    img1 = _shift(img0, 8.0, 0.0)
    small = make_flow_estimator(FlowConfig(max_side=160))(img0, img1)  # 4x downscale inside
    assert np.median(small[40:-40, 40:-40, 0]) == pytest.approx(8.0, abs=0.5)


def test_forward_backward_mask_rejects_occlusion(teddy):
    img0 = teddy[0].image
    img1 = _shift(img0, 5.0, 3.0)
    # an occluder in img1: a patch of another part of the image pasted over the middle
    y0, x0, s = 180, 260, 100
    img1[y0 : y0 + s, x0 : x0 + s] = np.ascontiguousarray(img0[20 : 20 + s, 500 : 500 + s][::-1, ::-1])
    fe = make_flow_estimator(FlowConfig())
    fw, bw = fe(img0, img1), fe(img1, img0)
    mask = forward_backward_mask(fw, bw, 2.0)
    occluded = np.zeros(mask.shape, bool)
    occluded[y0 + 7 : y0 + s - 13, x0 + 5 : x0 + s - 15] = True  # img0 pixels hidden by the patch in img1
    clear = np.zeros(mask.shape, bool)
    clear[40:150, 40:200] = True
    assert mask[occluded].mean() < 0.3, mask[occluded].mean()
    assert mask[clear].mean() > 0.8, mask[clear].mean()


def test_forward_backward_mask_flags_targets_outside():
    H, W = 20, 30
    fw = np.zeros((H, W, 2), np.float32)
    fw[..., 0] = 10.0
    bw = -fw
    m = forward_backward_mask(fw, bw, 0.5)
    assert m[:, : W - 10].all() and not m[:, W - 9 :].any()


def test_compose_and_resize():
    H, W = 24, 32
    a = np.full((H, W, 2), [2.0, 1.0], np.float32)
    b = np.full((H, W, 2), [-1.0, 3.0], np.float32)
    c = compose_flows(a, b)
    assert np.allclose(c[: H - 2, : W - 3], [1.0, 4.0])
    r = resize_flow(a, W * 2, H * 2)
    assert r.shape == (H * 2, W * 2, 2) and np.allclose(r, [4.0, 2.0])


def test_unknown_method_and_adapter_slot():
    with pytest.raises(FlowError, match="unknown flow.method"):
        make_flow_estimator(FlowConfig(method="raft"))
    calls = []

    def factory(cfg):
        def est(img0, img1):
            calls.append(cfg.max_side)
            return np.zeros(img0.shape[:2] + (2,), np.float32)

        return est

    register_flow_method("zeros_test", factory)
    fe = make_flow_estimator(FlowConfig(method="zeros_test", max_side=99))
    assert fe(np.zeros((4, 5, 3)), np.zeros((4, 5, 3))).shape == (4, 5, 2) and calls == [99]
    with pytest.raises(FlowError):
        make_flow_estimator(FlowConfig())(np.zeros((4, 5, 3)), np.zeros((5, 5, 3)))
