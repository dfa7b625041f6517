"""The scale-drift measurement s = exp(log D(i-1,K) - log D(i,0)) of the shared frame."""

import numpy as np
import pytest

from gsslam.factors import median_depth_ratio
from gsslam.factors.errors import FactorInputError


def _two_layer_depth(rng, h=60, w=80):
    """A near object (1 m) in front of a far wall (4 m): the bimodal depth of TUM teddy."""
    d = np.full((h, w), 4.0) + rng.normal(scale=0.01, size=(h, w))
    d[5:55, 5:50] = 1.0 + rng.normal(scale=0.005, size=(50, 45))
    return d


def test_ratio_uses_pixels_valid_in_both_maps():
    rng = np.random.default_rng(0)
    true_ratio = 1.7
    prev = _two_layer_depth(rng)
    new = prev / true_ratio
    # the two maps cover different parts of the frame: prev misses most of the wall, new the object
    prev[:, 50:] = np.nan
    new[5:55, 5:40] = np.nan
    ratio = median_depth_ratio(prev, new)
    assert ratio == pytest.approx(true_ratio, rel=0.02)
    # the ratio of medians over different pixel sets is badly biased in this scene
    a, b = prev[np.isfinite(prev)], new[np.isfinite(new)]
    assert abs(np.median(a) / np.median(b) / true_ratio - 1) > 0.3


def test_ratio_falls_back_to_medians_for_different_sizes():
    prev = np.full((6, 8), 2.0)
    new = np.full((3, 4), 1.0)
    assert median_depth_ratio(prev, new) == pytest.approx(2.0)


def test_ratio_needs_depth_in_both_maps():
    with pytest.raises(FactorInputError, match="valid depths"):
        median_depth_ratio(np.full((4, 4), np.nan), np.ones((4, 4)))
