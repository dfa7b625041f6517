"""Valid values of every config key (``RANGES``) and :func:`validate_config`, which checks a loaded config."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

from gsslam.config_schema import Config, ConfigError


@dataclass(frozen=True)
class Range:
    """Valid values of one numeric key: ``lo <= v <= hi`` (``<`` where open); None: unbounded."""

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False

    def ok(self, v: float) -> bool:
        if not math.isfinite(v):
            return False
        if self.lo is not None and (v <= self.lo if self.lo_open else v < self.lo):
            return False
        return not (self.hi is not None and (v >= self.hi if self.hi_open else v > self.hi))

    def describe(self, integer: bool = False) -> str:
        def num(x: float) -> str:
            return str(int(x)) if integer else f"{x:g}"

        parts = []
        if self.lo is not None:
            parts.append(f"{'>' if self.lo_open else '>='} {num(self.lo)}")
        if self.hi is not None:
            parts.append(f"{'<' if self.hi_open else '<='} {num(self.hi)}")
        kind = "an integer" if integer else "a finite number"
        return f"{kind} " + " and ".join(parts) if parts else kind


POS = Range(0.0, lo_open=True)  # > 0
NONNEG = Range(0.0)  # >= 0
UNIT = Range(0.0, 1.0)  # [0, 1]
PROB = Range(0.0, 1.0, lo_open=True)  # (0, 1]


def _ge(n: int) -> Range:
    return Range(float(n))


# Every numeric key has a range; string keys with a fixed vocabulary list their choices. A new config
# key needs an entry here (tests/test_config.py checks that none is missing).
RANGES: dict[str, Range | tuple[str, ...]] = {
    "mode": ("mono", "rgbd"),
    "seed": Range(0, 2**32 - 1),
    "flow.dis_preset": ("ultrafast", "fast", "medium"),
    "flow.dis_finest_scale": _ge(-1),
    "flow.max_side": _ge(16),
    "flow.fb_threshold_px": POS,
    "keyframes.min_flow_px": NONNEG,
    "keyframes.max_gap": _ge(1),
    "encoder.submap_size": _ge(1),
    "encoder.max_points_per_frame": _ge(8),
    "encoder.min_parallax_deg": Range(0.0, 90.0, hi_open=True),
    "encoder.ransac_threshold_px": POS,
    "encoder.min_depth": NONNEG,
    "encoder.max_depth": POS,
    "encoder.pointmap_max_side": _ge(16),
    "encoder.min_inliers": _ge(5),
    "encoder.odometry_depth_diff_max": POS,
    "encoder.min_texture_gradient": NONNEG,
    "encoder.mono_dis_preset": ("", "ultrafast", "fast", "medium"),
    "encoder.mono_shared_depth_sigma": Range(0.0, 1.0),
    "encoder.mono_shared_depth_min_confidence": Range(0.0, 1.0),
    "encoder.mono_essential_method": ("ransac", "magsac"),
    "encoder.mono_ba_tracks": ("two_view", "all"),
    "encoder.mono_two_view_hypotheses": Range(1, 16),
    "encoder.mono_link_min_confidence": Range(0.0, 1.0),
    "encoder.mono_link_max_spread": Range(0.0, 5.0),
    "encoder.mono_focal_frames": _ge(8),
    "encoder.mono_focal_min_dev": Range(0.0, 0.5),
    "encoder.mono_focal_min_gain": Range(0.0, 0.9),
    "encoder.rgbd_icp_auto_min_ratio": POS,
    "encoder.rgbd_icp_auto_max_ratio": POS,
    "encoder.rgbd_joint_flow_weight": POS,
    "encoder.colour_focal_frames": _ge(8),
    "encoder.colour_focal_max_frames": _ge(8),
    "encoder.colour_focal_min_dev": Range(0.0, 0.5),
    "encoder.colour_focal_min_baseline_m": Range(0.0, 0.2),
    "encoder.colour_focal_min_gain": Range(0.0, 0.9),
    "encoder.colour_focal_fallback_gap": Range(0, 16),
    "encoder.colour_registration_ratio": Range(0.0, 2.0),
    "encoder.colour_registration_baseline_m": Range(-0.2, 0.2),
    "encoder.colour_registration_given": ("depth", "colour"),
    "run.trajectory_camera": ("ground_truth", "colour", "depth"),
    "encoder.colour_registration_depth_rx_deg": Range(-10.0, 10.0),
    "encoder.colour_registration_depth_ry_deg": Range(-10.0, 10.0),
    "encoder.colour_registration_depth_rz_deg": Range(-10.0, 10.0),
    "encoder.depth_delay_frames": _ge(16),
    "encoder.colour_registration_depth_rotation_span": Range(8, 100000),
    "encoder.colour_registration_depth_rotation_min_deg": Range(0.0, 5.0),
    "encoder.depth_delay_s": Range(-0.1, 0.1),
    "encoder.depth_delay_min_s": Range(0.0, 0.1),
    "encoder.depth_delay_velocity_frames": Range(1, 10),
    "encoder.depth_delay_velocity": ("tracked", "depth"),
    "encoder.colour_registration_depth_mean_tol": Range(0.0, 0.2),
    "encoder.colour_registration_depth_interp_tol": Range(0.0, 0.2),
    "encoder.colour_registration_joint_weight": NONNEG,
    "encoder.colour_registration_flow_preset": ("", "ultrafast", "fast", "medium"),
    "encoder.colour_registration_flow_max_side": Range(0, 4096),
    "graph.flow_sigma_px": POS,
    "graph.flow_inlier_prior": PROB,
    "graph.flow_outlier_range_px": POS,
    "graph.scale_sigma": POS,
    "graph.mono_placeholder_scale_sigma": NONNEG,
    "graph.adjacency_sigma_m": POS,
    "graph.loop_sigma_m": POS,
    "graph.depth_prior_sigma": POS,
    "graph.prior_rot_sigma": POS,
    "graph.prior_trans_sigma": POS,
    "graph.prior_scale_sigma": POS,
    "graph.relinearize_threshold": NONNEG,
    "graph.relinearize_skip": _ge(1),
    "graph.relinearize_threshold_velocity": NONNEG,
    "graph.relinearize_threshold_bias": NONNEG,
    "graph.align_rot_sigma": POS,
    "graph.align_trans_sigma": POS,
    "graph.adjacency_max_points": _ge(1),
    "graph.flow_max_points": _ge(1),
    "graph.wildfire_threshold": NONNEG,
    "graph.batch_max_iterations": _ge(0),
    "graph.batch_solve": ("lm", "staged"),  # gsslam.graph.staged_solve.BATCH_SOLVES
    "graph.flow_effective_points": NONNEG,
    "graph.keyframe_refine_rot_sigma": POS,
    "graph.keyframe_refine_trans_sigma": POS,
    "graph.mono_stretch_sigma": POS,
    "imu.gyro_noise_density": POS,
    "imu.gyro_random_walk": POS,
    "imu.accel_noise_density": POS,
    "imu.accel_random_walk": POS,
    "imu.gravity": POS,
    "imu.static_window_s": POS,
    "imu.static_max_accel_std": POS,
    "imu.tie_rot_sigma": POS,
    "imu.tie_trans_sigma": POS,
    "imu.gravity_sigma": POS,
    "imu.accel_bias_sigma": POS,
    "imu.gyro_bias_sigma": POS,
    "imu.min_init_keyframes": _ge(3),
    "mapper.device": ("auto", "cpu", "cuda"),
    "mapper.rasterizer": ("auto", "c", "torch", "gsplat", "fast"),  # gsslam.mapping.rasterize.BACKENDS
    "mapper.max_side": _ge(16),
    "mapper.iterations": _ge(0),
    "mapper.window": _ge(1),
    "mapper.lambda_ssim": UNIT,
    "mapper.lambda_depth": NONNEG,
    "mapper.lambda_depth_normal": NONNEG,
    "mapper.lambda_scale": NONNEG,
    "mapper.lambda_flow": NONNEG,
    "mapper.lambda_pose_depth": NONNEG,
    "mapper.unmapped_alpha": UNIT,
    "mapper.max_gaussians": _ge(1),
    "mapper.depth_feedback_points": _ge(0),
    "mapper.lr_means": NONNEG,
    "mapper.lr_colors": NONNEG,
    "mapper.lr_opacity": NONNEG,
    "mapper.lr_scales": NONNEG,
    "mapper.lr_quats": NONNEG,
    "mapper.lr_exposure": NONNEG,
    "mapper.lambda_exposure": NONNEG,
    "mapper.lr_pose": NONNEG,
    "mapper.pose_iterations": _ge(0),
    "mapper.lr_pose_init": NONNEG,
    "mapper.init_stride": _ge(1),
    "mapper.init_opacity": Range(0.0, 1.0, lo_open=True, hi_open=True),
    "mapper.min_confidence": UNIT,
    "mapper.flow_sigma_px": POS,
    "mapper.flow_inlier_prior": PROB,
    "mapper.flow_outlier_range_px": POS,
    "mapper.densify_error": NONNEG,
    "mapper.prune_error": NONNEG,
    "mapper.min_opacity": Range(0.0, 1.0, hi_open=True),
    "mapper.revisit_fraction": UNIT,
    "mapper.final_iterations_per_keyframe": _ge(0),
    "mapper.final_lr_scale": POS,
    "mapper.final_densify_rounds": _ge(0),
    "mapper.final_lambda_flow": NONNEG,
    "mapper.final_pose_iterations": _ge(0),
    "mapper.final_lr_pose": NONNEG,
    "mapper.final_pose_prior": NONNEG,
    "mapper.pose_window": _ge(0),
    "mapper.lambda_pose_prior": NONNEG,
    "mapper.pose_prior_rel": POS,
    "mapper.pose_min_gain": UNIT,
    "mapper.pose_init_prior": NONNEG,
    "mapper.num_threads": _ge(0),
    "mapper.final_num_threads": _ge(0),
    "mapper.registration_iterations": _ge(1),
    "mapper.registration_jacobian": ("warp", "subpixel", "central"),
    "mapper.registration_min_coverage": UNIT,
    "mapper.registration_max_residual": POS,
    "mapper.registration_min_information": NONNEG,
    "mapper.registration_max_condition": _ge(1),
    "mapper.registration_information_scale": POS,
    "mapper.registration_step_halvings": _ge(0),
    "mapper.registration_unconverged_weight": UNIT,
    "mapper.registration_owner_split": UNIT,
    "mapper.feedback_min_age": _ge(0),
    "mapper.feedback_min_converged": UNIT,
    "mapper.final_max_iterations": _ge(0),
    "mapper.final_max_share": UNIT,
    "mapper.final_coarse_share": UNIT,
    "mapper.consolidate_per_keyframe": NONNEG,
    "mapper.consolidate_lr_scale": POS,
    "loop.skip_recent": _ge(0),
    "loop.min_overlap": UNIT,
    "loop.min_score": UNIT,
    "loop.min_inliers": _ge(3),
    "loop.inlier_threshold_m": POS,
    "loop.max_candidates": _ge(1),
    "loop.inlier_threshold_rel": POS,
    "loop.min_inlier_ratio": UNIT,
    "loop.ransac_iterations": _ge(1),
    "loop.depth_tolerance_rel": POS,
    "loop.max_view_angle_deg": Range(0.0, 180.0, lo_open=True),
    "loop.points_per_submap": _ge(1),
    "loop.orb_features": _ge(1),
    "loop.max_reprojection_checks": _ge(1),
    "loop.verify_view_pairs": _ge(1),
    "loop.max_drift_ratio": POS,
    "loop.max_rot_discrepancy_deg": Range(0.0, 180.0, lo_open=True),
    "loop.max_residual_factor": POS,
    "loop.rejoin_min_inliers": _ge(3),
    "loop.rejoin_min_inlier_ratio": UNIT,
    "loop.rejoin_min_fitness": UNIT,
    "loop.mono_sigma_min_rel": POS,
    "loop.mono_dcs_phi": NONNEG,
    "loop.mono_extent_sigma": NONNEG,
    "loop.mono_inlier_gate": ("median", "range", "ray"),
    "loop.ray_threshold_deg": Range(0.0, 90.0, lo_open=True),
    "loop.ray_depth_rel": POS,
    "loop.icp_refine_pairs": _ge(1),
    "loop.icp_loop_weight": POS,
    "loop.icp_effective_points": POS,
    "loop.icp_huber": _ge(0),
    "loop.icp_max_shift_m": POS,
    "loop.icp_neighbours": _ge(0),
    "loop.icp_neighbour_floor_m": NONNEG,
    "loop.icp_neighbour_floor_deg": NONNEG,
    "pipeline.track_points": _ge(8),
    "pipeline.min_photo_consistency": UNIT,
    "pipeline.min_pnp_inliers": _ge(4),
    "pipeline.min_pnp_inlier_ratio": UNIT,
    "pipeline.track_icp_min_fitness": UNIT,
    "pipeline.pnp_threshold_px": POS,
    "pipeline.blank_std": NONNEG,
    "pipeline.max_lost_frames": _ge(1),
    "pipeline.cross_flow_back": _ge(0),
    "pipeline.flow_points": _ge(1),
    "pipeline.max_time_gap_s": POS,
    "pipeline.pose_outlier_max_dev_m": NONNEG,
    "pipeline.pose_outlier_max_dev_deg": NONNEG,
    "pipeline.frame_pose_blend_gate_m": NONNEG,
    "pipeline.frame_pose_blend_gate_deg": NONNEG,
    "run.checkpoint_every": _ge(0),
    "run.native_eval_keyframes": _ge(0),
    "run.native_eval_held_out": _ge(0),
}


def _leaves(obj: Any, prefix: str = "") -> list[tuple[str, Any]]:
    out = []
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        out += _leaves(v, f"{prefix}{f.name}.") if dataclasses.is_dataclass(v) else [(f"{prefix}{f.name}", v)]
    return out


def validate_config(cfg: Config, sources: dict[str, str] | None = None) -> None:
    """Raise :class:`ConfigError` on the first value outside its range (``RANGES``); ``sources`` maps a
    dotted key to where it was set (for the message)."""
    sources = sources or {}

    def fail(key: str, value: Any, valid: str) -> None:
        where = sources.get(key)
        where = f"set {where}" if where else "(the default)"
        raise ConfigError(f"config {key}={value!r} {where} is out of range: must be {valid}")

    for key, value in _leaves(cfg):
        rule = RANGES.get(key)
        if isinstance(rule, tuple):
            if value not in rule:
                fail(key, value, "one of " + ", ".join(repr(c) for c in rule))
        elif isinstance(value, float) and not math.isfinite(value):
            fail(key, value, rule.describe() if rule else "a finite number")
        elif rule is not None and not isinstance(value, bool) and not rule.ok(float(value)):
            fail(key, value, rule.describe(integer=isinstance(value, int)))
    if not cfg.encoder.min_depth < cfg.encoder.max_depth:
        fail("encoder.max_depth", cfg.encoder.max_depth, f"> encoder.min_depth ({cfg.encoder.min_depth})")
