"""The built-in quick suite end to end (what CI runs as `gsslam bench accuracy --suite quick`)."""

from __future__ import annotations

import json
import time

import pytest


@pytest.mark.slow
def test_quick_suite_table(tmp_path):
    from typer.testing import CliRunner

    from gsslam.cli import app

    t0 = time.perf_counter()
    res = CliRunner().invoke(app, ["bench", "accuracy", "--suite", "quick", "--out", str(tmp_path)])
    seconds = time.perf_counter() - t0
    assert res.exit_code == 0, res.output
    rows = {r["sequence"]: r for r in json.loads((tmp_path / "results.json").read_text())["rows"]}
    assert set(rows) == {"teddy60_rgbd", "teddy60_mono", "synth_orbit"}
    assert all(r["status"] == "ok" and r["frames"] == 40 for r in rows.values())
    # measured: ATE 0.43 / 0.56 / 0.52 cm, keyframe PSNR 26.7 / 26.4 / 33.1 dB
    for name, r in rows.items():
        assert r["ate_m"] < 0.015, name
        assert r["psnr"] > 22.0 and 0.7 < r["ssim"] <= 1.0, name
        assert r["map_mb"] > 0.1 and r["fps"] > 0 and r["rpe_t_m"] < 0.01, name
    assert abs(rows["teddy60_rgbd"]["sim3_scale"] - 1.0) < 0.1  # RGB-D: metric scale
    assert "| default | 3 / 3 |" in (tmp_path / "results.md").read_text()
    print(f"quick suite: {seconds:.0f} s")
