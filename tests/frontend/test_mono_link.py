"""The mono scale link between two depth maps of a shared frame (gsslam.frontend.mono_link)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from gsslam.frontend.mono_link import chain_link, estimate_link, weighted_median


def _maps(rng, true_log=0.2, h=60, w=80):
    """A shared frame's depth in two submaps: half the pixels at high parallax (confidence 0.9-1, 2 %
    noise), half at low parallax (confidence 0.1-0.3) with a 30 % bias, as a rotation error over a small
    parallax gives (docs/results.md, "Drift on harder sequences, session 6")."""
    z = rng.uniform(1.0, 3.0, (h, w))
    prev = z * np.exp(rng.normal(0, 0.02, (h, w)))
    new = z * np.exp(-true_log) * np.exp(rng.normal(0, 0.02, (h, w)))
    conf = np.where(rng.random((h, w)) < 0.5, rng.uniform(0.9, 1.0, (h, w)), rng.uniform(0.1, 0.3, (h, w)))
    low = conf < 0.5
    new[low] *= 1.3
    new[rng.random((h, w)) < 0.1] = np.nan  # holes
    return prev, new, conf


def test_weighted_median():
    x, w = np.array([0.0, 1.0, 2.0, 3.0]), np.array([1.0, 1.0, 1.0, 10.0])
    assert weighted_median(x, w) == 3.0
    assert weighted_median(x, np.ones(4)) == 1.0  # the lower of the two middle values


def test_confidence_weighting_removes_the_low_parallax_bias():
    rng = np.random.default_rng(0)
    prev, new, conf = _maps(rng)
    plain = estimate_link(prev, new, None, None)
    weighted = estimate_link(prev, new, conf, conf)
    gated = estimate_link(prev, new, conf, conf, min_confidence=0.5)
    # half the pixels 30 % too deep: the plain median is off by 0.206 (measured), the weighted one
    # by 0.008, the gated one by 0.0006
    assert abs(plain.log_scale - 0.2) > 0.1
    assert abs(weighted.log_scale - 0.2) < 0.03
    assert abs(gated.log_scale - 0.2) < 0.005
    # the spread of the per-pixel ratios: bimodal without the gate (measured 0.165), 2 x 2 % noise with it
    # (measured 0.028); sigma = spread / sqrt(50 independent pixels)
    assert gated.spread < 0.04 < plain.spread
    assert np.isclose(gated.sigma, gated.spread / np.sqrt(50))


def test_too_few_pixels_give_none():
    prev = np.full((10, 10), np.nan)
    prev[0, :5] = 1.0
    assert estimate_link(prev, np.ones((10, 10)), None, None) is None


def test_chain_link_default_is_the_plain_median():
    rng = np.random.default_rng(1)
    prev, new, conf = _maps(rng)
    cfg = SimpleNamespace(min_inliers=20, mono_link_weighted=False, mono_link_min_confidence=0.0)
    both = np.isfinite(prev) & np.isfinite(new)
    link = chain_link(prev, new, conf, conf, cfg)
    assert link.log_scale == float(np.median(np.log(prev[both]) - np.log(new[both])))
    cfg.mono_link_weighted = True
    assert abs(chain_link(prev, new, conf, conf, cfg).log_scale - 0.2) < 0.03
