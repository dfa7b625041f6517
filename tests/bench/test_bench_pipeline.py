"""``gsslam bench pipeline --lengths``: per-stage time per frame and memory of whole runs."""

from __future__ import annotations

import pytest

from gsslam.bench.pipeline import run_lengths

pytestmark = pytest.mark.slow  # whole runs

SMALL = [
    "mapper.max_side=80",
    "mapper.iterations=5",
    "mapper.final_iterations_per_keyframe=2",
    "mapper.device=cpu",
]


def test_lengths_report_stages_memory_and_a_chart(bundled_tum, tmp_path):
    res = run_lengths(bundled_tum, lengths=(20, 40), pattern="f", overrides=SMALL, plot=tmp_path / "rss.png")
    a, b = res["runs"]
    assert (a["frames"], b["frames"]) == (20, 40)
    for r in (a, b):
        assert set(r["ms_per_frame"]) == {"tracking", "map", "loops", "batch", "final pass", "outputs"}
        assert r["ms_per_frame"]["map"] > 0 and r["ms_per_frame"]["tracking"] > 0
        assert 0 < r["final_pass_share"] < 1 and r["peak_rss_mb"] > 100
        assert r["cpu_s"] > 0
    assert len(res["rss_by_frame"]["40 frames"]) == 4  # every 10 frames
    assert (tmp_path / "rss.png").stat().st_size > 1000
