"""Image quality metrics for rendered vs. observed images: PSNR and SSIM (numpy in, floats out).

Images are ``[H, W, 3]`` (or ``[H, W]``) float arrays with values in ``[0, data_range]``.

SSIM is ``gsslam.imaging`` (the one implementation, shared with the mapping loss) run in float64.
It follows Wang et al. 2004 ("Image quality assessment: from error visibility to structural
similarity"): a Gaussian window with sigma 1.5 truncated at 3.5 sigma (11 x 11), K1 = 0.01,
K2 = 0.03, population (co)variances, symmetric padding at the border; the mean is taken over the
pixels whose window lies inside the image (a 5-pixel border is left out) and over channels. These are
the settings ``skimage.metrics.structural_similarity(gaussian_weights=True, sigma=1.5,
use_sample_covariance=False, data_range=1)`` documents as matching Wang et al.
"""

from __future__ import annotations

import numpy as np
import torch

from gsslam.eval import EvalError
from gsslam.imaging import RADIUS, gaussian_window
from gsslam.imaging import ssim_map as _ssim_map


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


def gaussian_kernel(sigma: float = 1.5) -> np.ndarray:  # -> [2r+1] (11 for sigma 1.5), sums to 1
    return gaussian_window(sigma).numpy()


def ssim_map(
    a: np.ndarray,  # [H, W, 3] or [H, W]
    b: np.ndarray,  # same shape as a
    data_range: float = 1.0,
) -> np.ndarray:  # [H, W, C] local SSIM (C = 1 for grayscale input)
    """Per-pixel, per-channel SSIM (``gsslam.imaging.ssim_map``, computed in float64)."""
    a, b = _check_pair(a, b)
    if a.ndim == 2:
        a, b = a[..., None], b[..., None]
    try:
        return _ssim_map(torch.from_numpy(a), torch.from_numpy(b), data_range).numpy()
    except ValueError as e:
        raise ImageMetricError(str(e)) from None


def ssim(a: np.ndarray, b: np.ndarray, data_range: float = 1.0) -> float:
    """Mean SSIM of ``a``, ``b`` ([H, W, 3], same shape) over the interior and the channels; 1.0 if equal."""
    m = ssim_map(a, b, data_range)
    return float(m[RADIUS:-RADIUS, RADIUS:-RADIUS].mean())
