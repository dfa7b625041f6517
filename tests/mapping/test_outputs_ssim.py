"""The map evaluation's float32 SSIM against the metric module's float64 one (issue #17)."""

from __future__ import annotations

import numpy as np

from gsslam.eval.image_metrics import ssim
from gsslam.mapping.outputs import ssim_float32


def test_float32_ssim_matches_the_metric_at_native_resolution(teddy_frames):
    # two real 640x480 teddy frames 5 apart (SSIM 0.63) and a frame against a noisy copy of itself
    # (0.43); measured float32 - float64 differences 4.5e-6 and 8.7e-6 (0 for identical images)
    a, b = (f.image.astype(np.float32) for f in teddy_frames[:2])
    noisy = np.clip(a + np.random.default_rng(0).normal(0, 0.05, a.shape), 0, 1).astype(np.float32)
    for x, y in ((a, b), (a, noisy), (a, a)):
        ref = ssim(x.astype(np.float64), y.astype(np.float64))
        assert abs(ssim_float32(x, y) - ref) < 5e-5
    assert ssim(a, b) < 0.8  # the pairs are not trivially alike
