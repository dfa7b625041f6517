"""What a run estimates from its first frames before tracking: the depth-to-colour registration (RGB-D:
ratio, baseline, the depth camera's turn from edges, the colour-depth delay;
:mod:`gsslam.frontend.depth_registration`) and the mono focal length (:mod:`gsslam.frontend.mono_focal`)."""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np

from gsslam.config import Config
from gsslam.frontend.depth_registration import (
    IDENTITY,
    DepthRegistration,
    edge_turn_correction,
    registration_correction,
    with_delay,
)
from gsslam.frontend.flow import make_flow_estimator
from gsslam.frontend.mono_focal import mono_focal_correction
from gsslam.frontend.registration_retiming import retime_frame

__all__ = ["applied_delay", "colour_registration", "mono_focal_calibration", "registration_flow_config"]

log = logging.getLogger(__name__)

DELAY_FIELDS = (  # the delay's record, kept when the registration is estimated again
    "delay_s_estimated", "delay_ok", "delay_std_s", "delay_reason", "delay_pairs", "delay_rms_deg",
    "delay_s_whole_image", "delay_bands_s",
)  # fmt: skip


def applied_delay(cfg: Config, est: DepthRegistration | None) -> float:
    """The colour-depth delay a run re-times its depth by (s; 0: none): ``encoder.depth_delay_s`` when given,
    else the estimate's (``encoder.depth_delay_auto``) where it is trusted and at least
    ``encoder.depth_delay_min_s`` (smaller ones are within the estimate's own error on synchronised data)."""
    enc = cfg.encoder
    if cfg.mode != "rgbd":
        return 0.0
    if enc.depth_delay_s:
        return float(enc.depth_delay_s)
    if not enc.depth_delay_auto or est is None or not est.delay_ok:
        return 0.0
    tau = float(est.delay_s_estimated)
    if abs(tau) < enc.depth_delay_min_s:
        log.info("colour-depth delay %.1f ms estimated: below %.1f ms, not applied", 1e3 * tau,
                 1e3 * enc.depth_delay_min_s)  # fmt: skip
        return 0.0
    log.info("colour-depth delay %.1f ms estimated (sd %.1f): depth re-timed by it", 1e3 * tau,
             1e3 * est.delay_std_s)  # fmt: skip
    return tau


def colour_registration(ds, cfg: Config, max_frames: int | None):  # -> (to apply, estimate | None)
    """RGB-D: depth-to-colour registration from the first frames (frontend/depth_registration.py), as a
    run estimates it; a run that applies a registration also takes its poses from depth (``rgbd_icp``).
    Windows of ``encoder.colour_focal_frames`` are read in turn, up to ``colour_focal_max_frames``, until
    one gives the estimate evidence (``ok``); none: a warning, and the depth is used as given."""
    enc = cfg.encoder
    if cfg.mode == "rgbd" and enc.colour_registration_ratio > 0:  # given: no estimate
        reg = DepthRegistration(
            enc.colour_registration_ratio, enc.colour_registration_baseline_m, enc.colour_registration_given,
            ok=True, given_by_config=True, depth_rotation_deg=(
                enc.colour_registration_depth_rx_deg, enc.colour_registration_depth_ry_deg,
                enc.colour_registration_depth_rz_deg,
            ),
        )  # fmt: skip
        log.info("depth-to-colour registration given: k %.4f, baseline %.1f mm, intrinsics of the %s camera, "
                 "depth camera turned %s deg", reg.ratio, 1000 * reg.baseline_m, reg.given,
                 reg.depth_rotation_deg)  # fmt: skip
        return reg, None
    if cfg.mode != "rgbd" or not enc.colour_focal_auto:
        return IDENTITY, None
    end = min(len(ds), max_frames or len(ds), max(enc.colour_focal_max_frames, enc.colour_focal_frames))
    flow = make_flow_estimator(registration_flow_config(cfg))
    reg, est, start = IDENTITY, None, 0
    given_delay = float(enc.depth_delay_s) if enc.colour_registration_retime else 0.0

    def estimate(frames, delay_s: float):
        return registration_correction(
            frames, flow, min_dev=enc.colour_focal_min_dev, min_baseline_m=enc.colour_focal_min_baseline_m,
            min_gain=enc.colour_focal_min_gain, fallback_gap=enc.colour_focal_fallback_gap or None,
            joint_weight=enc.colour_registration_joint_weight, handeye=enc.colour_registration_handeye,
            delay_s=delay_s,
        )  # fmt: skip

    while start == 0 or start + 8 <= end:  # the next frames when these gave no evidence (e.g. a bare wall)
        frames = [ds[i] for i in range(start, min(start + enc.colour_focal_frames, end))]
        reg, est = estimate(frames, given_delay)
        if est is None or est.ok:
            break
        start += enc.colour_focal_frames
    if est is not None and not est.ok:
        log.warning(
            "depth-to-colour registration: no evidence in the first %d frames (%d flow pairs with depth "
            "geometry); depth is used as given. If it is not registered to colour, results suffer "
            "(docs/frontend.md)", end, est.pairs,
        )  # fmt: skip
    elif start > 0:
        log.info("depth-to-colour registration estimated from frames %d-%d", start, start + len(frames) - 1)
    tau = 0.0  # a delay estimated here and applied (below)
    if enc.depth_delay_auto and est is not None and not reg.is_identity():  # applied by applied_delay
        stop = min(len(ds), max_frames or len(ds), start + enc.depth_delay_frames)
        est = with_delay(est, [ds[i] for i in range(start, stop)], flow)
        tau = applied_delay(cfg, est) if enc.colour_registration_retime and not given_delay else 0.0
        if tau:  # the registration again, its pairs re-timed by the delay it led to (session 18)
            reg, again = estimate(frames, tau)
            est = replace(again, **{f: getattr(est, f) for f in DELAY_FIELDS}) if again is not None else est
    if enc.colour_registration_depth_rotation_auto and est is not None and not reg.is_identity():
        span = min(len(ds), max_frames or len(ds), enc.colour_registration_depth_rotation_span)
        picks = [int(i) for i in np.unique(np.linspace(0, span - 1, 20).round())]
        delay = given_delay or tau
        if delay:  # each depth at its colour image's time, a frame without a velocity left out (session 18)
            frames = [f for f in (
                retime_frame(ds[i - 1] if i > 0 else None, ds[i], ds[i + 1] if i + 1 < span else None, delay)
                for i in picks
            ) if f is not None]  # fmt: skip
        else:
            frames = [ds[i] for i in picks]
        reg, est = edge_turn_correction(
            frames, reg, est, enc.colour_registration_depth_rotation_baseline,
            enc.colour_registration_depth_rotation_min_deg,
        )  # fmt: skip
    return reg, est


def registration_flow_config(cfg: Config):
    """The flow of the registration estimate: ``cfg.flow`` with ``encoder.colour_registration_flow_*``."""
    enc = cfg.encoder
    return replace(
        cfg.flow, dis_preset=enc.colour_registration_flow_preset or cfg.flow.dis_preset,
        max_side=enc.colour_registration_flow_max_side or cfg.flow.max_side,
    )  # fmt: skip


def mono_focal_calibration(ds, cfg: Config, max_frames: int | None):  # -> (focal scale, estimate | None)
    """Mono: focal self-calibration from the first frames (frontend/mono_focal.py)."""
    nominal = cfg.encoder.mono_focal_auto_nominal and getattr(ds, "intrinsics_nominal", False)
    if cfg.mode != "mono" or not (cfg.encoder.mono_focal_auto or nominal):
        return 1.0, None
    if nominal and not cfg.encoder.mono_focal_auto:
        log.info(
            "mono focal: %s hands out nominal intrinsics; calibrating the focal",
            getattr(ds, "name", "the dataset"),
        )
    n = min(len(ds), cfg.encoder.mono_focal_frames, max_frames or len(ds))
    return mono_focal_correction([ds[i] for i in range(n)], make_flow_estimator(cfg.flow), cfg.encoder)
