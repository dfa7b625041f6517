"""The runner's depth-to-colour registration reads further when the first frames give no evidence
(run/sequence.py ``colour_registration``): a camera that starts still (here: at a bare wall in the long
synthetic room, docs/results.md session 12) has no flow pairs with geometry in its first window, and its
unregistered depth used as given cost 10.8 cm there."""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np
import pytest

from gsslam.config import load_config
from gsslam.datasets.misregistered import misregister_depth
from gsslam.run.sequence import colour_registration
from helpers.tum import TUM_FR3, load_tum

KINECT_RATIO = 1.114
BASELINE_M = 0.025


@pytest.fixture(scope="module")
def still_then_moving(bundled_tum):
    """20 copies of the first frame (no motion: no pairs), then 20 moving frames; depth misregistered
    and handed out with the depth camera's intrinsics, as 7-Scenes does."""
    intr = replace(TUM_FR3, fx=TUM_FR3.fx * KINECT_RATIO, fy=TUM_FR3.fy * KINECT_RATIO)
    frames = [f for f in load_tum(bundled_tum, list(range(0, 24))) if f.depth is not None][:20]
    frames = [
        replace(f, depth=misregister_depth(f.depth, TUM_FR3, BASELINE_M, KINECT_RATIO), intrinsics=intr)
        for f in frames
    ]
    still = [replace(frames[0], index=i) for i in range(20)]
    return still + [replace(f, index=20 + i) for i, f in enumerate(frames)]


@pytest.mark.slow  # ~1 min CPU: two windows, the second fits the colour hypothesis (ICP over focal lengths)
def test_registration_read_further_when_the_start_is_still(still_then_moving, caplog):
    ds = still_then_moving
    first_only = load_config(
        None, ["encoder.colour_focal_frames=20", "encoder.colour_focal_max_frames=20"], mode="rgbd"
    )
    with caplog.at_level(logging.WARNING, logger="gsslam.run.sequence"):
        reg, est = colour_registration(ds, first_only, None)
    assert reg.is_identity() and not est.ok and est.pairs < 3, est
    assert "no evidence in the first 20 frames" in caplog.text

    cfg = load_config(None, ["encoder.colour_focal_frames=20"], mode="rgbd")  # colour_focal_max_frames=200
    reg, est = colour_registration(ds, cfg, None)
    assert not reg.is_identity() and est.ok, est
    # measured k 1.109, baseline 25.1 mm from the second window (12 pairs); the first: 0 pairs
    assert abs(est.ratio / KINECT_RATIO - 1) < 0.02 and abs(est.baseline_m - BASELINE_M) < 0.006, est


def test_given_registration_carries_the_depth_camera_turn():
    """``encoder.colour_registration_depth_r{x,y,z}_deg`` (session 16) reach the applied registration."""
    cfg = load_config(None, [
        "encoder.colour_registration_ratio=1.114", "encoder.colour_registration_baseline_m=0.025",
        "encoder.colour_registration_depth_rx_deg=0.5", "encoder.colour_registration_depth_rz_deg=-0.2",
    ], mode="rgbd")  # fmt: skip
    reg, est = colour_registration(None, cfg, None)
    assert est is None and reg.given_by_config and reg.depth_rotation_deg == (0.5, 0.0, -0.2)
    R = reg.R_colour_depth()
    assert R[2, 1] == pytest.approx(np.radians(0.5), rel=1e-3)
    assert R[1, 0] == pytest.approx(np.radians(-0.2), rel=1e-3)
