"""A run given the delay between its colour and depth images (``encoder.depth_delay_s``) re-times every
frame's depth but the first two and writes the depth camera at its image's time: end to end on the first 40
frames of the simulated Kinect room with its depth taken 16 ms after its colour (docs/results.md, session 17)."""

from __future__ import annotations

import json

import pytest

from gsslam.config import load_config
from gsslam.datasets.synthetic import SyntheticDataset
from gsslam.run.sequence import run_dataset

ROOM = dict(
    n_frames=1000, width=320, height=240, scene="furnished_room", trajectory="room_walk", seed=0,
    sensor="kinect_v1", misregister={"baseline_m": 0.025, "focal_scale": 1.114, "report": "depth",
                                     "ground_truth": "depth"},
    degrade={"shutter": 0.5, "exposure_amp": 0.25, "exposure_period": 150}, depth_delay_s=0.016,
)  # fmt: skip
GIVEN = ["mapper.enabled=false", "loop.enabled=false", "encoder.colour_registration_ratio=1.114",
         "encoder.colour_registration_baseline_m=0.025"]  # fmt: skip


@pytest.mark.slow  # two 40-frame runs, ~25 s CPU each
def test_run_retimes_the_depth(tmp_path):
    ate = {}
    for delay in (0.0, 0.016):
        cfg = load_config(None, [*GIVEN, f"encoder.depth_delay_s={delay}"], mode="rgbd")
        run_dataset(SyntheticDataset(**ROOM), cfg, tmp_path / str(delay), max_frames=40)
        m = json.loads((tmp_path / str(delay) / "metrics.json").read_text())
        ate[delay] = m["ate"]["rmse_m"]
        assert m["frames_posed"] == 40
        if delay:
            assert m["depth_retiming"] == {"delay_s": delay, "frames_retimed": 38, "frames_not_retimed": 2}
            assert m["trajectory_camera"]["delay_s"] == delay
        else:
            assert "depth_retiming" not in m and "delay_s" not in m["trajectory_camera"]
    print("ATE", ate)
    assert ate[0.016] < 0.6 * ate[0.0], ate  # measured MEASURED
