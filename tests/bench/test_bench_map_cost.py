"""``gsslam bench map-cost``: whole runs with the map off and at each mapper resolution."""

from __future__ import annotations

import pytest

from gsslam.bench.map_cost import run

pytestmark = pytest.mark.slow  # whole runs

SMALL = ["mapper.iterations=5", "mapper.final_iterations_per_keyframe=2", "mapper.device=cpu"]


def test_map_cost_reports_ratio_and_native_psnr_per_side(bundled_tum):
    res = run(bundled_tum, sides=(40, 80), max_frames=20, overrides=SMALL)
    off, a, b = res["runs"]
    assert off["max_side"] == "off" and off["ratio_cpu"] == 1.0 and res["frames"] == 20
    assert (a["max_side"], b["max_side"]) == (40, 80)
    for r in (a, b):
        assert r["ratio_cpu"] > 1.0  # the map costs something
        assert r["map_steps"] > 0 and 0 < r["final_pass_share"] < 1
        assert 10.0 < r["psnr_keyframes_native"] < r["psnr_keyframes"]  # native is the harder score
    assert b["num_gaussians"] > a["num_gaussians"]  # more pixels, more seeds
