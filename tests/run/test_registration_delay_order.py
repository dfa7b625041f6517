"""What the registration estimate is told about the colour-depth delay (session 18): a given delay
re-times its pairs from the start; an estimated one that is applied makes it estimate again, re-timed; none,
or the option off, runs it as before. The estimates themselves are replaced by recorders (their behaviour:
tests/frontend/test_registration_retiming.py)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import gsslam.run.registration as registration
from gsslam.config import load_config
from gsslam.frontend.depth_registration import DepthRegistration
from gsslam.types import CameraIntrinsics, Frame

INTR = CameraIntrinsics(fx=4.0, fy=4.0, cx=1.5, cy=1.5, width=4, height=4)
FRAMES = [Frame(k, k / 30.0, np.zeros((4, 4, 3)), INTR, np.ones((4, 4), np.float32)) for k in range(200)]


@pytest.fixture
def calls(monkeypatch):
    seen = []

    def estimate(frames, flow, delay_s=0.0, **kw):  # the baseline read depends on the delay it was told
        seen.append(delay_s)
        est = DepthRegistration(1.114, 0.030 - delay_s, ok=True, pairs=8)
        return est, est

    def with_delay(est, frames, flow):
        return replace(
            est, delay_s_estimated=0.012, delay_ok=True, delay_std_s=0.001, delay_pairs=20,
            delay_s_whole_image=0.02, delay_bands_s=(0.011, 0.012, 0.013),
        )  # fmt: skip

    monkeypatch.setattr(registration, "registration_correction", estimate)
    monkeypatch.setattr(registration, "with_delay", with_delay)
    return seen


def _run(*sets):
    cfg = load_config(None, ["encoder.colour_registration_depth_rotation_auto=false", *sets], mode="rgbd")
    return registration.colour_registration(FRAMES, cfg, None)


def test_no_delay_estimates_as_before(calls):
    reg, est = _run("encoder.depth_delay_auto=false")
    assert calls == [0.0] and reg.baseline_m == 0.030


def test_a_given_delay_re_times_the_estimate(calls):
    reg, _ = _run("encoder.depth_delay_s=0.016")
    assert calls == [0.016] and reg.baseline_m == pytest.approx(0.014)
    _run("encoder.depth_delay_s=0.016", "encoder.colour_registration_retime=false")
    assert calls == [0.016, 0.0]  # the option off: the estimate reads the frames as they come


def test_an_applied_estimate_estimates_again(calls):
    reg, est = _run("encoder.depth_delay_auto=true")
    assert calls == [0.0, 0.012]  # estimate -> delay -> estimate re-timed by it
    assert reg.baseline_m == pytest.approx(0.018) and est.baseline_m == pytest.approx(0.018)
    assert est.delay_s_estimated == 0.012 and est.delay_ok and est.delay_pairs == 20  # its record kept
    assert est.delay_s_whole_image == 0.02 and est.delay_bands_s == (0.011, 0.012, 0.013)
    _run("encoder.depth_delay_auto=true", "encoder.depth_delay_min_s=0.02")  # estimated, not applied
    assert calls == [0.0, 0.012, 0.0]
    _run("encoder.depth_delay_auto=true", "encoder.depth_delay_s=-0.008")  # given wins: one estimate
    assert calls[-1:] == [-0.008] and len(calls) == 4
