"""Image quality metrics for rendered vs. observed images: PSNR and SSIM (pure numpy).

Images are ``[H, W, 3]`` (or ``[H, W]``) float arrays with values in ``[0, data_range]``.

SSIM follows Wang et al. 2004 ("Image quality assessment: from error visibility to structural
similarity"): a Gaussian window with sigma 1.5 truncated at 3.5 sigma (11 x 11), K1 = 0.01,
K2 = 0.03, population (co)variances, symmetric padding at the border; the mean is taken over the
pixels whose window lies inside the image (a 5-pixel border is left out) and over channels. These are
the settings ``skimage.metrics.structural_similarity(gaussian_weights=True, sigma=1.5,
use_sample_covariance=False, data_range=1)`` documents as matching Wang et al.
"""

from __future__ import annotations

import numpy as np

from gsslam.eval import EvalError


class ImageMetricError(EvalError):
    """The two images (or the mask) do not have matching, usable shapes."""


def _check_pair(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape != b.shape:
        raise ImageMetricError(f"images must have the same shape, got {a.shape} and {b.shape}")
    if a.ndim not in (2, 3):
        raise ImageMetricError(f"images must be [H, W, 3] or [H, W], got shape {a.shape}")
    return a, b


def psnr(
    a: np.ndarray,  # [H, W, 3]
    b: np.ndarray,  # [H, W, 3]
    mask: np.ndarray | None = None,  # [H, W] bool: pixels to include
    data_range: float = 1.0,
) -> float:
    """Peak signal-to-noise ratio in dB, ``10 log10(data_range^2 / MSE)``; ``inf`` for identical images."""
    a, b = _check_pair(a, b)
    sq = (a - b) ** 2
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != a.shape[:2]:
            raise ImageMetricError(f"mask must be [H, W] = {a.shape[:2]}, got {mask.shape}")
        if not mask.any():
            raise ImageMetricError("mask selects no pixels; PSNR is undefined")
        sq = sq[mask]
    mse = float(np.mean(sq))
    if mse == 0.0:
        return float("inf")
    return float(10.0 * np.log10(data_range**2 / mse))


def gaussian_kernel(sigma: float = 1.5, truncate: float = 3.5) -> np.ndarray:  # -> [2r+1], sums to 1
    r = int(truncate * sigma + 0.5)
    x = np.arange(-r, r + 1, dtype=np.float64)
    w = np.exp(-0.5 * (x / sigma) ** 2)
    return w / w.sum()


def _blur(img: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Separable filter of ``img`` [H, W, C] with kernel ``w`` [2r+1], symmetric border padding."""
    r = len(w) // 2
    h, wd = img.shape[:2]
    p = np.pad(img, ((r, r), (0, 0), (0, 0)), mode="symmetric")
    rows = sum(w[k] * p[k : k + h] for k in range(len(w)))
    p = np.pad(rows, ((0, 0), (r, r), (0, 0)), mode="symmetric")
    return sum(w[k] * p[:, k : k + wd] for k in range(len(w)))


def ssim_map(
    a: np.ndarray,  # [H, W, 3] or [H, W]
    b: np.ndarray,  # same shape as a
    data_range: float = 1.0,
    sigma: float = 1.5,
) -> np.ndarray:  # [H, W, C] local SSIM (C = 1 for grayscale input)
    """Per-pixel, per-channel SSIM (Wang et al. 2004) with a Gaussian window."""
    a, b = _check_pair(a, b)
    if a.ndim == 2:
        a, b = a[..., None], b[..., None]
    w = gaussian_kernel(sigma)
    if min(a.shape[:2]) < len(w):
        raise ImageMetricError(f"SSIM needs images of at least {len(w)}x{len(w)} pixels, got {a.shape[:2]}")
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    mu_a, mu_b = _blur(a, w), _blur(b, w)
    var_a = _blur(a * a, w) - mu_a**2
    var_b = _blur(b * b, w) - mu_b**2
    cov = _blur(a * b, w) - mu_a * mu_b
    num = (2 * mu_a * mu_b + c1) * (2 * cov + c2)
    den = (mu_a**2 + mu_b**2 + c1) * (var_a + var_b + c2)
    return num / den


def ssim(a: np.ndarray, b: np.ndarray, data_range: float = 1.0) -> float:
    """Mean SSIM of ``a``, ``b`` ([H, W, 3], same shape) over the interior and the channels; 1.0 if equal."""
    m = ssim_map(a, b, data_range)
    r = len(gaussian_kernel()) // 2
    return float(m[r:-r, r:-r].mean())
