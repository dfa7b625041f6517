"""Scale factors on Similarity3 variables (SING3R scale drift, and a scale prior for RGB-D gauges).

Scale drift: submap i's units relate to submap i-1's through the shared frame's robust depth
statistics, ``s_i = exp(log D(i-1, K) - log D(i, 0))`` (D = median depth of the shared frame in each
submap). With ``E = S_{i-1}^-1 S_i`` the relative scale ``s_E = s_b / s_a`` must equal ``s_i``.

Residual (dimension 1, unitless log-scale)::

    r = log s_b - log s_a - log s_meas

Jacobians in GTSAM's Similarity3 chart (omega, u, lambda): ``dr/dlambda_b = 1``, ``dr/dlambda_a = -1``.
This is exactly the 7th row of ``BetweenFactorSimilarity3``.

Scale prior (dimension 1): ``r = log s - log s_prior``.
"""

from __future__ import annotations

import gtsam
import numpy as np

from ._lie import check_positive, fill


def median_depth_ratio(depth_prev: np.ndarray, depth_next: np.ndarray) -> float:
    """``s = exp(log D(i-1, K) - log D(i, 0))`` from two depth maps of the same (shared) frame.

    ``depth_prev``, ``depth_next``: [h, w] depths of the shared frame in the previous and the new
    submap (NaN / <= 0 ignored). When both maps have the same size, ``s`` is the median over the
    pixels valid in BOTH of the per-pixel log ratio: medians over different pixel sets are biased
    in scenes with several depth layers (a near object and a far wall covered unequally by the two
    maps gave scale errors of 1.1-4x on TUM teddy). Otherwise (different sizes, or fewer than 3
    common pixels) it falls back to the ratio of the two medians.
    """
    from .errors import FactorInputError

    a = np.asarray(depth_prev, dtype=np.float64)
    b = np.asarray(depth_next, dtype=np.float64)
    ok_a, ok_b = np.isfinite(a) & (a > 0), np.isfinite(b) & (b > 0)
    if a.shape == b.shape:
        both = ok_a & ok_b
        if both.sum() >= 3:
            return float(np.exp(np.median(np.log(a[both]) - np.log(b[both]))))
    a, b = a[ok_a], b[ok_b]
    if len(a) < 3 or len(b) < 3:
        raise FactorInputError(
            f"scale drift needs valid depths of the shared frame in both submaps, got {len(a)} and {len(b)}"
        )
    return float(np.median(a) / np.median(b))


def make_scale_factor(key_a: int, key_b: int, log_scale: float, sigma: float) -> gtsam.CustomFactor:
    """``log s_b - log s_a ~ log_scale`` on two Similarity3 keys (``sigma`` in log units)."""
    log_scale = float(log_scale)
    if not np.isfinite(log_scale):
        from .errors import FactorInputError

        raise FactorInputError(f"log_scale must be finite, got {log_scale}")
    noise = gtsam.noiseModel.Isotropic.Sigma(1, check_positive("sigma", sigma))
    JA = np.array([[0, 0, 0, 0, 0, 0, -1.0]])
    JB = np.array([[0, 0, 0, 0, 0, 0, 1.0]])

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H) -> np.ndarray:
        ka, kb = this.keys()
        sa, sb = values.atSimilarity3(ka).scale(), values.atSimilarity3(kb).scale()
        fill(H, 0, JA)
        fill(H, 1, JB)
        return np.array([np.log(sb) - np.log(sa) - log_scale])

    return gtsam.CustomFactor(noise, [key_a, key_b], error)


def make_scale_prior_factor(key: int, scale: float, sigma: float) -> gtsam.CustomFactor:
    """``log s ~ log scale`` on one Similarity3 key (e.g. every RGB-D submap keeps scale 1)."""
    log_s0 = np.log(check_positive("scale", scale))
    noise = gtsam.noiseModel.Isotropic.Sigma(1, check_positive("sigma", sigma))
    J = np.array([[0, 0, 0, 0, 0, 0, 1.0]])

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H) -> np.ndarray:
        fill(H, 0, J)
        return np.array([np.log(values.atSimilarity3(this.keys()[0]).scale()) - log_s0])

    return gtsam.CustomFactor(noise, [key], error)
