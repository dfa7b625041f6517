"""A registration given by the configuration (``encoder.colour_registration_*``) replaces the estimate:
the instrument that measures a run at the true registration (docs/results.md, session 13)."""

from __future__ import annotations

import pytest

from gsslam.config import load_config
from gsslam.config_schema import ConfigError
from gsslam.frontend.depth_registration import DepthRegistration
from gsslam.frontend.registration_record import registration_record
from gsslam.run.sequence import colour_registration


class _NoFrames:
    """A dataset that must not be read: a given registration estimates nothing."""

    def __len__(self) -> int:
        return 40

    def __getitem__(self, i):
        raise AssertionError("a given registration must not read frames")


def test_given_registration_is_applied_without_an_estimate():
    cfg = load_config(
        None,
        ["encoder.colour_registration_ratio=1.114", "encoder.colour_registration_baseline_m=0.025"],
        mode="rgbd",
    )
    reg, est = colour_registration(_NoFrames(), cfg, None)
    assert est is None and reg.given_by_config and not reg.is_identity()
    assert (reg.ratio, reg.baseline_m, reg.given) == (1.114, 0.025, "depth")
    rec = registration_record(reg, est)
    assert rec["given"] and rec["applied"] and rec["baseline_m_applied"] == 0.025
    assert "ratio_estimated" not in rec
    # off (0, the default): the runner estimates; mono never registers
    mono = load_config(None, ["encoder.colour_registration_ratio=1.114"], mode="mono")
    assert colour_registration(_NoFrames(), mono, None)[0].is_identity()


def test_registration_record_of_an_estimate_not_applied():
    est = DepthRegistration(1.003, -0.004, "depth", 0.95, 0.97, 12, 9000, True)
    rec = registration_record(DepthRegistration(ok=True), est)
    assert not rec["given"] and not rec["applied"] and rec["pairs"] == 12 and rec["ok"]
    assert rec["ratio_estimated"] == pytest.approx(1.003) and rec["baseline_m_estimated"] == -0.004


def test_given_registration_keys_are_checked():
    with pytest.raises(ConfigError):
        load_config(None, ["encoder.colour_registration_given=infrared"], mode="rgbd")
    with pytest.raises(ConfigError):
        load_config(None, ["encoder.colour_registration_ratio=-1"], mode="rgbd")
