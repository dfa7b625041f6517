"""Which colour-depth delay a run re-times its depth by: given, estimated and trusted, or none."""

from __future__ import annotations

from dataclasses import replace

from gsslam.config import load_config
from gsslam.frontend.depth_registration import DepthRegistration
from gsslam.run.registration import applied_delay

EST = DepthRegistration(1.114, 0.025, ok=True, delay_s_estimated=0.0105, delay_ok=True, delay_std_s=0.0008)


def _cfg(*sets, mode="rgbd"):
    return load_config(None, list(sets), mode=mode)


def test_given_delay_wins_over_the_estimate():
    assert applied_delay(_cfg("encoder.depth_delay_s=-0.008"), EST) == -0.008
    assert applied_delay(_cfg("encoder.depth_delay_s=-0.008", "encoder.depth_delay_auto=true"), EST) == -0.008


def test_estimate_applied_only_when_asked_trusted_and_large_enough():
    auto = _cfg("encoder.depth_delay_auto=true")
    assert applied_delay(_cfg("encoder.depth_delay_auto=false"), EST) == 0.0  # auto off: recorded only
    assert applied_delay(_cfg(), EST) == 0.0105  # on by default (session 18)
    assert applied_delay(auto, EST) == 0.0105
    assert applied_delay(auto, replace(EST, delay_ok=False)) == 0.0  # not observed / not trusted
    assert applied_delay(auto, replace(EST, delay_s_estimated=-0.0011)) == 0.0  # within the synchronised spread
    assert applied_delay(auto, replace(EST, delay_s_estimated=-0.0031)) == -0.0031
    assert applied_delay(auto, None) == 0.0  # no registration estimated
    assert applied_delay(_cfg("encoder.depth_delay_auto=true", mode="mono"), EST) == 0.0
