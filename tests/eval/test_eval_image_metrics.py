"""PSNR and SSIM: identities, hand-computed cases, and an independent filter on a real image."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from gsslam.eval.image_metrics import ImageMetricError, gaussian_kernel, psnr, ssim, ssim_map

C1, C2 = 0.01**2, 0.03**2


@pytest.fixture(scope="module")
def teddy_image(bundled_tum) -> np.ndarray:  # [H, W, 3] float in [0, 1], a real frame at half size
    path = sorted((bundled_tum / "rgb").glob("*.png"))[0]
    img = cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB).astype(np.float64) / 255.0
    return cv2.resize(img, (160, 120), interpolation=cv2.INTER_AREA)


def test_identical_images(teddy_image):
    assert psnr(teddy_image, teddy_image) == float("inf")
    assert ssim(teddy_image, teddy_image) == pytest.approx(1.0, abs=1e-12)


def test_psnr_hand_computed():
    a = np.full((8, 10, 3), 0.5)
    b = a + 0.1  # MSE = 0.01 -> 20 dB
    assert psnr(a, b) == pytest.approx(20.0, abs=1e-9)
    b2 = a.copy()
    b2[:4] += 0.2  # half the pixels off by 0.2
    mask = np.zeros((8, 10), dtype=bool)
    mask[:4] = True
    assert psnr(a, b2, mask=mask) == pytest.approx(10 * np.log10(1 / 0.04), abs=1e-9)
    assert psnr(a, b2, mask=~mask) == float("inf")
    assert psnr(a, b2) == pytest.approx(10 * np.log10(1 / 0.02), abs=1e-9)
    assert psnr(a * 255, b * 255, data_range=255.0) == pytest.approx(20.0, abs=1e-9)


def test_ssim_of_flat_images_is_the_luminance_term():
    a, b = np.full((20, 20, 3), 0.3), np.full((20, 20, 3), 0.7)
    expected = (2 * 0.3 * 0.7 + C1) / (0.3**2 + 0.7**2 + C1)  # variances and covariance are 0
    assert ssim(a, b) == pytest.approx(expected, abs=1e-12)


def test_ssim_single_window_hand_computed():
    # An 11x11 image has one interior pixel whose Gaussian window is exactly the whole image.
    rng = np.random.default_rng(0)
    a = rng.uniform(size=(11, 11, 3))
    b = np.clip(a + rng.normal(scale=0.1, size=a.shape), 0, 1)
    g = gaussian_kernel(1.5)
    assert len(g) == 11
    W = np.outer(g, g)
    vals = []
    for c in range(3):
        x, y = a[..., c], b[..., c]
        mx, my = (W * x).sum(), (W * y).sum()
        vx, vy = (W * (x - mx) ** 2).sum(), (W * (y - my) ** 2).sum()
        cxy = (W * (x - mx) * (y - my)).sum()
        vals.append((2 * mx * my + C1) * (2 * cxy + C2) / ((mx**2 + my**2 + C1) * (vx + vy + C2)))
    assert ssim(a, b) == pytest.approx(np.mean(vals), abs=1e-12)


def test_ssim_matches_an_independent_gaussian_filter_on_a_real_image(teddy_image):
    ndimage = pytest.importorskip("scipy.ndimage")
    rng = np.random.default_rng(1)
    noise = rng.normal(scale=0.02, size=teddy_image.shape)
    b = np.clip(cv2.GaussianBlur(teddy_image, (5, 5), 1.0) + noise, 0, 1)

    def f(x):
        return ndimage.gaussian_filter(x, sigma=(1.5, 1.5, 0), truncate=3.5, mode="reflect")

    mx, my = f(teddy_image), f(b)
    vx, vy = f(teddy_image**2) - mx**2, f(b**2) - my**2
    cxy = f(teddy_image * b) - mx * my
    ref = (2 * mx * my + C1) * (2 * cxy + C2) / ((mx**2 + my**2 + C1) * (vx + vy + C2))
    np.testing.assert_allclose(ssim_map(teddy_image, b), ref, atol=1e-10)
    assert ssim(teddy_image, b) == pytest.approx(ref[5:-5, 5:-5].mean(), abs=1e-12)


def test_ssim_properties(teddy_image):
    rng = np.random.default_rng(2)
    shape = teddy_image.shape
    noisy = [np.clip(teddy_image + rng.normal(scale=s, size=shape), 0, 1) for s in (0.01, 0.05, 0.2)]
    scores = [ssim(teddy_image, n) for n in noisy]
    assert 1.0 > scores[0] > scores[1] > scores[2] > 0.0
    assert ssim(noisy[1], teddy_image) == pytest.approx(scores[1], abs=1e-12)  # symmetric
    gray = teddy_image.mean(axis=2)
    assert ssim(gray, gray) == pytest.approx(1.0, abs=1e-12)
    assert ssim(teddy_image, 1.0 - teddy_image) < 0.0  # inverted structure


def test_image_metric_errors():
    a = np.zeros((12, 12, 3))
    with pytest.raises(ImageMetricError, match="same shape"):
        psnr(a, np.zeros((12, 13, 3)))
    with pytest.raises(ImageMetricError, match="at least 11x11"):
        ssim(np.zeros((8, 20, 3)), np.zeros((8, 20, 3)))
    with pytest.raises(ImageMetricError, match="no pixels"):
        psnr(a, a, mask=np.zeros((12, 12), dtype=bool))
    with pytest.raises(ImageMetricError, match="mask must be"):
        psnr(a, a, mask=np.ones((3, 3), dtype=bool))
