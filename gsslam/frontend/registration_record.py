"""The ``colour_focal`` record of ``metrics.json``: the depth-to-colour registration a run applied and the
estimate behind it (:mod:`gsslam.frontend.depth_registration`: ratio and baseline; the turn from edges,
:mod:`gsslam.frontend.registration_edges`; the colour-depth delay,
:mod:`gsslam.frontend.registration_delay`)."""

from __future__ import annotations

import numpy as np

from gsslam.frontend.depth_registration import DepthRegistration

__all__ = ["registration_record"]


def registration_record(applied: DepthRegistration, est: DepthRegistration | None) -> dict:
    """The registration a run used and the estimate behind it, for ``metrics.json``."""
    rec: dict = {
        "given": applied.given_by_config, "applied": not applied.is_identity(),
        "ratio_applied": float(applied.ratio), "baseline_m_applied": float(applied.baseline_m),
    }  # fmt: skip
    if applied.delay_s:
        rec["delay_s_applied"] = float(applied.delay_s)
    if any(applied.depth_rotation_deg):
        rec["depth_rotation_deg_applied"] = [float(x) for x in applied.depth_rotation_deg]
    if est is not None:
        rec.update({
            "ratio_estimated": float(est.ratio), "baseline_m_estimated": float(est.baseline_m),
            "intrinsics_given_for": est.given, "pairs": est.pairs, "points": est.points, "ok": est.ok,
            "cost_px_at_1": est.cost_registered, "cost_px_at_ratio": est.cost,
            "pair_baselines_m": list(est.pair_baselines_m),
        })  # fmt: skip
        if np.isfinite(est.baseline_m_fixed_motion):
            rec["baseline_m_fixed_motion"] = float(est.baseline_m_fixed_motion)
        if est.edge_turn is not None:
            t = est.edge_turn
            rec.update({
                "depth_rotation_deg_estimated": list(t.rotation_deg), "depth_rotation_observed": t.observed,
                "depth_rotation_points": [t.points_u, t.points_v], "depth_rotation_frames": t.frames,
                "depth_rotation_score": [t.score_unturned, t.score], "depth_rotation_shift_px": t.shift_px,
                "depth_rotation_baseline_m_edges": t.baseline_m,
                "depth_rotation_deg_with_edges_baseline": list(t.rotation_deg_with_baseline),
            })  # fmt: skip
        if np.isfinite(est.baseline_m_handeye):
            rec["baseline_m_handeye"] = float(est.baseline_m_handeye)
            rec["handeye_median_chi2"] = float(est.handeye_median_chi2)
        if np.isfinite(est.delay_s_estimated) or est.delay_reason:
            rec.update({
                "delay_s_estimated": float(est.delay_s_estimated), "delay_ok": est.delay_ok,
                "delay_std_s": float(est.delay_std_s), "delay_reason": est.delay_reason,
                "delay_pairs": est.delay_pairs, "delay_rms_deg_at_zero": float(est.delay_rms_deg[0]),
                "delay_rms_deg": float(est.delay_rms_deg[1]),
                "delay_s_whole_image": float(est.delay_s_whole_image),
                "delay_bands_s": [float(x) for x in est.delay_bands_s],
            })  # fmt: skip
    else:
        rec["intrinsics_given_for"] = applied.given
    return rec
