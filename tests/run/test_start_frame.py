"""`gsslam run --start-frame`: a run part-way into a real sequence tracks those frames, evaluated against
the whole sequence's ground truth by timestamp."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from gsslam.datasets import open_dataset
from gsslam.io.trajectory import read_tum


@pytest.mark.slow
def test_cli_run_from_a_start_frame(bundled_tum, tmp_path):
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "gsslam.cli", "run", str(bundled_tum), "--mode", "rgbd", "--out", str(out),
           "--start-frame", "30", "--max-frames", "12", "--set", "mapper.enabled=false",
           "--no-progress"]  # fmt: skip
    subprocess.run(cmd, check=True, capture_output=True, timeout=300)
    stamps = open_dataset("tum", bundled_tum).timestamps()
    traj = read_tum(out / "trajectory.tum")
    assert list(traj.timestamps) == stamps[30:42]
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["provenance"]["start_frame"] == 30
    # 12 frames of slow hand-held motion: measured 0.33 cm; a wrong ground-truth pairing would be > 10 cm
    assert metrics["ate"]["pairs"] == 12 and metrics["ate"]["rmse_m"] < 0.01
    assert len(list((out / "keyframes").glob("*"))) > 0  # keyframe images read back by range index
