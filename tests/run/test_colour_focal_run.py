"""A run on simulated unregistered Kinect v1 depth registers it (focal ratio, baseline, whose intrinsics)
and uses ICP poses, whether the dataset gives the depth camera's intrinsics (7-Scenes) or the colour
camera's; a run on registered depth leaves both alone (end to end, bundled teddy frames)."""

from __future__ import annotations

import json

import pytest
import yaml

from gsslam.config import load_config
from gsslam.datasets.base import open_dataset
from gsslam.run.sequence import run_dataset

MISREG = {"baseline_m": 0.025, "focal_scale": 1.114, "report": "depth"}
MISREG_COLOUR = {**MISREG, "report": "colour"}


@pytest.mark.slow
@pytest.mark.parametrize("misregister", [MISREG, MISREG_COLOUR, None])
def test_run_registers_unregistered_depth(bundled_tum, tmp_path, misregister):
    ds = open_dataset("playback", bundled_tum, pattern="f", n=40, misregister=misregister)
    cfg = load_config(None, ["mapper.enabled=false", "loop.enabled=false"], mode="rgbd")
    run_dataset(ds, cfg, tmp_path / "run", max_frames=40)
    m = json.loads((tmp_path / "run" / "metrics.json").read_text())
    saved = yaml.safe_load((tmp_path / "run" / "config.yaml").read_text())
    focal = m["colour_focal"]
    if misregister is None:
        assert not focal["applied"] and abs(focal["ratio_estimated"] - 1) < 0.01  # measured 1.002
        assert saved["encoder"]["rgbd_icp"] is False
    else:
        assert focal["applied"]
        assert abs(focal["ratio_estimated"] / 1.114 - 1) < 0.015  # measured 1.126 / 1.108
        assert focal["intrinsics_given_for"] == misregister["report"]
        assert abs(focal["baseline_m_estimated"] - 0.025) < 0.005  # measured 25.9 / 26.4 mm
        assert saved["encoder"]["rgbd_icp"] is True
        intr = yaml.safe_load((tmp_path / "run" / "intrinsics.yaml").read_text())
        assert intr["fx"] == pytest.approx(535.4, rel=0.015)  # measured 529.7 (depth given), 535.4 (colour)
    assert m["frames_posed"] == 40
