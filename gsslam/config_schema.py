"""The configuration tree: one frozen section dataclass per stage, under :class:`Config`.

Loading (YAML + dotted overrides) is in :mod:`gsslam.config`, the valid ranges in
:mod:`gsslam.config_ranges`; import the sections from :mod:`gsslam.config`, which re-exports them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from gsslam.errors import GsslamError

# fmt: off
# (one line per field, comment included: docs/make_config_doc.py reads them so)


class ConfigError(GsslamError):
    """A config file or override names an unknown key or a value of the wrong type."""


@dataclass(frozen=True)
class FlowConfig:
    method: str = "dis"  # "dis" | "farneback"
    dis_preset: str = (
        "ultrafast"  # "ultrafast" | "fast" | "medium" (ultrafast: ~3x faster, see docs/results.md)
    )
    dis_finest_scale: int = (
        0  # DIS pyramid level of the output (0: the downscaled image itself; -1: preset's)
    )
    max_side: int = 320  # flow is computed on images downscaled so that max(H, W) <= this
    fb_threshold_px: float = 2.0  # forward-backward consistency threshold, in full-resolution pixels


@dataclass(frozen=True)
class KeyframeConfig:
    min_flow_px: float = 12.0  # median flow (at full resolution) that makes a new keyframe
    max_gap: int = 10  # at most this many frames between keyframes


@dataclass(frozen=True)
class EncoderConfig:
    submap_size: int = 6  # K: keyframes per submap after the shared one
    max_points_per_frame: int = 3000  # correspondences / points sampled per frame
    min_parallax_deg: float = 1.0  # below this, mono triangulation is not trusted
    ransac_threshold_px: float = 1.0
    min_depth: float = 0.1
    max_depth: float = 10.0
    pointmap_max_side: int = 320  # point maps / local estimation at max(H, W) <= this (TUM -> 320x240)
    min_inliers: int = 30  # PnP / essential-matrix inliers below this: the estimate is not trusted
    rgbd_odometry: bool = (
        False  # also run open3d hybrid RGB-D odometry (measured worse on TUM teddy, see docs)
    )
    odometry_depth_diff_max: float = 0.07  # metres; open3d odometry correspondence gate
    rgbd_icp: bool = False  # RGB-D: always refine PnP poses by dense point-to-plane ICP on depth (frontend/icp.py)
    rgbd_icp_auto: bool = True  # RGB-D: use ICP once PnP and ICP rotations disagree (colour not calibrated to depth)
    rgbd_icp_auto_min_ratio: float = 0.96  # PnP / ICP rotation ratio below this: colour and depth disagree
    rgbd_icp_auto_max_ratio: float = 1.08  # above this (ICP itself turns ~3 % short on TUM teddy: 1.02-1.05)
    rgbd_icp_direct: bool = True  # and register each keyframe directly to the submap's frame 0 by ICP
    rgbd_joint_pose: bool = True  # RGB-D: keyframe poses from flow (PnP inliers) and depth (point-to-plane) jointly (frontend/joint_pose.py)
    rgbd_joint_flow_weight: float = 1.0  # weight of the flow term against the depth term in that joint pose
    rgbd_joint_with_icp: bool = True  # that joint pose also where rgbd_icp is set (registered depth), unless ColourDepthCheck finds a mismatch
    colour_focal_auto: bool = True  # RGB-D: depth-to-colour registration from the first frames (depth_registration.py)
    colour_focal_frames: int = 40  # frames read for that estimate
    colour_focal_max_frames: int = 200  # ... read further, that many frames at most, while those give no evidence (e.g. a bare wall)
    colour_focal_min_dev: float = 0.02  # correct intrinsics + register depth only when |ratio - 1| exceeds this
    colour_focal_min_baseline_m: float = 0.01  # ... or |depth-colour baseline| exceeds this (m)
    colour_focal_min_gain: float = 0.15  # ... and the fit lowers the flow reprojection error by this fraction
    colour_focal_fallback_gap: int = 2  # frame pairs this far apart when 4 apart gives too few (a quick hand); 0: off
    colour_registration_ratio: float = 0.0  # RGB-D: > 0 GIVES the registration's f_depth / f_colour (no estimate; a measuring instrument)
    colour_registration_baseline_m: float = 0.0  # ... with this depth-to-colour baseline along x (m)
    colour_registration_depth_mean_tol: float = 0.0  # re-projected depth: mean of the samples within this relative depth of the nearest (0: nearest)
    colour_registration_icp: bool = True  # a run that registers its depth takes its poses from depth too (forces rgbd_icp)
    colour_registration_depth_interp_tol: float = 0.03  # re-projected depth: read bilinearly at the exact pixel where the 4 agree within this relative depth (0: nearest pixel; on since session 14)
    colour_registration_joint_weight: float = 0.0  # > 0: the estimate's baseline from each pair's motion re-solved with its flow, ICP's depth information a prior of this weight (registration_joint.py; 0: ICP motions held)
    colour_registration_handeye: bool = True  # the estimate's baseline from each pair's colour motion (flow) against its depth motion (ICP, smoothed normals), pooled by their covariances, where the pairs agree (registration_handeye.py; else the fit's; on since session 15)
    colour_registration_flow_preset: str = "medium"  # DIS preset of the registration estimate's flow ("": flow.dis_preset; medium: ~10x less flow bias than ultrafast, session 14)
    colour_registration_flow_max_side: int = 0  # ... computed at this max image side (0: flow.max_side)
    colour_registration_given: str = "depth"  # ... and the dataset's intrinsics belong to this camera (depth | colour)
    colour_registration_depth_rx_deg: float = 0.0  # ... and the depth camera turned against the colour one: R_colour_depth's rotation vector, x (deg; session 16)
    colour_registration_depth_ry_deg: float = 0.0  # ... y
    colour_registration_depth_rz_deg: float = 0.0  # ... z
    depth_delay_auto: bool = True  # RGB-D, registration estimated: also estimate the colour-depth delay (depth image this long after its colour image) from the two cameras' rotation rates per band of image rows (registration_delay.py; recorded in metrics.json colour_focal) and re-time the depth by it where trusted (depth_retiming.py; depth_delay_s, when given, wins; session 17, on since session 18: synchronised rows read under 1 ms and run as before)
    depth_delay_frames: int = 120  # ... over this many frames from the registration's window (the first 40 rarely turn at a changing rate)
    depth_delay_min_s: float = 0.003  # ... applied (with depth_delay_auto) only when at least this large (s): synchronised data read -1.9..+0.4 ms (session 17)
    colour_registration_depth_rotation_auto: bool = True  # RGB-D: estimate the depth camera's turn from depth vs colour edges and apply it with an estimated registration (registration_edges.py; session 17)
    colour_registration_depth_rotation_span: int = 200  # ... from 20 frames spread over this many first frames
    colour_registration_depth_rotation_min_deg: float = 0.15  # ... applied only when turned at least this much about x or y (deg): unturned synthetic rooms read up to 0.09 (session 17)
    colour_registration_depth_rotation_baseline: bool = False  # ... and apply the baseline the edges fit with the turn instead of the estimate's (session 17)
    depth_delay_s: float = 0.0  # RGB-D: each depth image taken this long AFTER its colour image (s; negative: before): its depth re-projected by the colour camera's motion over it (depth_retiming.py; 0: off)
    depth_delay_velocity_frames: int = 1  # ... the colour camera's velocity over the delay from the last this many + 1 tracked poses (1: the last two; more: a smaller feedback gain, more lag; session 17)
    depth_delay_prime: bool = True  # ... the first frames (before tracking gives a velocity) re-timed by the velocity of ICP between the first two raw depth images, read one frame ahead (the first frame starts the map; session 18)
    depth_delay_velocity: str = "tracked"  # ... the velocity over the delay: "tracked" (the last tracked poses, depth_delay_velocity_frames) or "depth" (ICP between the previous and this frame's raw depth images: not fed back by tracking; the tracked poses where ICP refuses; session 18)
    colour_registration_retime: bool = True  # ... the registration estimate's pairs re-timed by the applied delay (given, or estimated with depth_delay_auto: then estimated again), their depth images and ICP motion moved to the colour images' times by ICP velocities of the neighbouring raw depth images (registration_retiming.py; acts only with a delay; session 18)
    min_texture_gradient: float = 0.01  # mono: pixels below this local gradient (intensity/px) get no depth
    mono_dis_preset: str = ""  # DIS preset of the mono encoder's flows ("": the pipeline's; docs/results.md)
    mono_shared_depth_sigma: float = 0.0  # mono: relative std of the shared frame's depth as a prior in the local BA (0: off)
    mono_shared_depth_by_confidence: bool = True  # mono: that std / the shared depth's confidence (parallax / 4 min_parallax)
    mono_shared_depth_min_confidence: float = 0.5  # mono: no prior where that confidence is below this
    mono_essential_method: str = "ransac"  # mono: robust estimator of the two-view essential matrix (ransac | magsac)
    mono_ba_tracks: str = "two_view"  # mono: local BA tracks: the essential inliers (two_view) or all sampled (all)
    mono_two_view_hypotheses: int = 1  # mono: two-view poses (RANSAC samples) carried through PnP + BA; the best over all tracks is kept
    mono_link_weighted: bool = False  # mono: the scale link to the previous submap weighted by both depths' confidence (frontend/mono_link.py)
    mono_link_min_confidence: float = 0.0  # mono: with mono_link_weighted, pixels whose lower confidence is below this are not used
    mono_turn_rotation: bool = True  # mono: a low-parallax window keeps its rotation where PnP against the carried depth fails (PnP against a plane: a rotation-only model) instead of copying the previous pose
    mono_world_depth: bool = True  # mono: a shared frame whose carried depth a low-parallax turn exhausted takes the chain's earlier measured depths rendered at its pose instead of a placeholder plane (slam/world_depth.py; on since session 15)
    mono_world_depth_unlinked: bool = True  # mono, with mono_world_depth: a window whose own depth could not link to the carried depth (a sliver a turn left) is encoded again with the rendered depth filling the rest (slam/world_depth.py; on since session 15)
    mono_link_max_spread: float = 0.15  # mono: a two-view window whose frame-0 depth disagrees with the shared depth by a robust log-ratio spread above this is refused (a wrong two-view geometry) and carries the shared depth like a low-parallax one (0: off; 0.15 since session 15: right windows 0.003-0.075, the broken one 0.25)
    mono_focal_auto: bool = False  # mono: focal self-calibration from the first frames (frontend/mono_focal.py); off: docs/results.md sessions 10, 13
    mono_focal_auto_nominal: bool = True  # mono: ... and whenever the dataset says its intrinsics are nominal (7-Scenes: the depth camera's; docs/frontend.md)
    mono_focal_frames: int = 60  # frames read for that estimate
    mono_focal_min_dev: float = 0.05  # correct the focal only when |estimate / given - 1| exceeds this
    mono_focal_min_gain: float = 0.005  # ... and the estimate lowers the windows' BA cost by this fraction (0.01 before session 16: docs/results.md "The hidden room's own path")


@dataclass(frozen=True)
class GraphConfig:
    flow_sigma_px: float = 1.0
    flow_inlier_prior: float = 0.9  # inlier probability of the robust flow likelihood
    flow_outlier_range_px: float = 50.0  # width of the uniform outlier density
    scale_sigma: float = 0.05  # std of the log-scale drift factor
    mono_placeholder_scale_sigma: float = 0.0  # mono: std of the log-scale factor of a submap whose shared frame had only a placeholder depth (a low-parallax turn: its scale was guessed, not measured); 0: scale_sigma
    adjacency_sigma_m: float = (
        0.05  # aggregate std of a submap pair's shared-frame points (per point: * sqrt(N))
    )
    flow_effective_points: float = 10.0  # >0: a flow factor weighs as this many independent matches (0: per match)
    loop_sigma_m: float = 0.05
    depth_prior_sigma: float = 0.05  # relative (inverse-depth) std of mapper depth priors
    prior_rot_sigma: float = 1e-4
    prior_trans_sigma: float = 1e-4
    prior_scale_sigma: float = 1e-4
    relinearize_threshold: float = 0.01
    relinearize_skip: int = 1
    # per key character (checked against every variable: gsslam.graph.relinearization); 0: as above
    relinearize_threshold_velocity: float = 0.1  # IMU velocities (key character v, m/s)
    relinearize_threshold_bias: float = 0.1  # IMU biases (key character b, m/s^2 and rad/s)
    final_batch_refinement: bool = True
    keyframe_refine: bool = False  # RGB-D: then a batch with one pose per keyframe (corrections inside submaps)
    keyframe_refine_rot_sigma: float = 0.001  # rad, a keyframe's correction against its submap's local pose
    keyframe_refine_trans_sigma: float = 0.001  # m
    # mono: one log-stretch variable per submap scaling its local keyframe translations only (not its
    # depth), prior mean 0 with std mono_stretch_sigma (gsslam.graph.stretch; docs/graph.md)
    mono_translation_stretch: bool = False  # mono: a log-stretch per submap on its keyframe translations only
    mono_stretch_sigma: float = 0.07  # std of that stretch's prior (mean 0), log
    mono_stretch_flow: bool = True  # the cross-submap flow factors read the stretched local poses too

    align_rot_sigma: float = 0.01  # rad, rigid submap alignment through the shared frame
    align_trans_sigma: float = 0.02  # previous submap's units
    adjacency_max_points: int = 200  # shared-frame points per adjacency factor
    flow_max_points: int = 1000  # correspondences kept per flow factor (evenly subsampled)
    wildfire_threshold: float = 0.001  # iSAM2 Gauss-Newton wildfire threshold
    batch_max_iterations: int = 100  # Levenberg-Marquardt iterations of refine_batch
    # the final batch: "lm" one Levenberg-Marquardt; "staged" first with the robust kernels off (flow
    # Gaussian, ICP without Huber), then the run's factors from there (gsslam.graph.staged_solve)
    batch_solve: str = "lm"


@dataclass(frozen=True)
class MapperConfig:
    enabled: bool = True
    device: str = "auto"  # "auto" | "cpu" | "cuda"
    rasterizer: str = "auto"  # "auto" | "c" | "torch" | "gsplat" (docs/rasterizer.md); c: fail if not built
    max_side: int = 160  # mapper resolution: images downscaled so max(H, W) <= this
    iterations: int = 30  # optimisation steps per map update (60 before issue #17: docs/results.md)
    window: int = 8  # keyframes in the sliding window
    lambda_ssim: float = 0.2
    lambda_depth: float = 5.0  # inverse-depth L1 (lambda_D, SING3R)
    lambda_depth_normal: float = 0.05  # lambda_DN
    lambda_scale: float = 10.0  # lambda_S
    lambda_flow: float = 1.0
    lambda_pose_depth: float = 10.0  # intra-submap pose refinement, scale-invariant depth term
    pose_refinement: bool = (
        False  # keyframe pose refinement against the map; off: the graph discards it (docs)
    )
    unmapped_alpha: float = 0.5  # pixels with rendered alpha below this are "unmapped"
    max_gaussians: int = 50000
    depth_feedback: bool = False  # send rendered depths back to the graph (see docs)
    depth_feedback_points: int = 500  # rendered depths per new keyframe sent to the graph as depth priors
    shared_depth_feedback: bool = (
        False  # rendered depth of the shared keyframe seeds the next submap's encoding
    )
    lr_means: float = 1e-3
    lr_colors: float = 2.5e-2
    lr_opacity: float = 5e-2
    lr_scales: float = 5e-3
    lr_quats: float = 1e-3
    exposure: bool = True  # per-keyframe affine colour (log gain + bias per channel) optimised with the map (docs/mapping.md)
    lr_exposure: float = 5e-3  # Adam step of those exposures
    lambda_exposure: float = 0.01  # L2 pull of each exposure towards the identity
    zoom_low_pass: bool = True  # renders finer than the mapper's scale the 0.3 px^2 screen dilation by the zoom^2 (docs/mapping.md)
    lr_pose: float = 1e-3  # Adam step of the keyframe se(3) pose deltas (rad, world units)
    pose_iterations: int = 20  # pose-only refinement of each new keyframe against the frozen map
    lr_pose_init: float = 2e-3  # Adam step of that pose-only refinement
    init_stride: int = 2  # new Gaussians from every init_stride-th pixel (mapper resolution)
    init_opacity: float = 0.7
    min_confidence: float = 0.1  # point-map pixels below this confidence seed no Gaussians
    flow_sigma_px: float = 1.0  # robust flow likelihood, at mapper resolution
    flow_inlier_prior: float = 0.9
    flow_outlier_range_px: float = 20.0
    densify_error: float = 0.5  # mean normalized error that triggers clone/split (see docs/mapping.md)
    prune_error: float = 2.0  # mean normalized error that prunes a Gaussian
    min_opacity: float = 0.05  # Gaussians below this opacity are pruned
    revisit_fraction: float = 0.3  # share of optimize steps on a random keyframe older than the window
    consolidate_per_keyframe: float = 0.0  # per new keyframe, this many steps on older ones during the run (final pass spread out; docs)
    consolidate_coarse: bool = False  # those steps render at half resolution (mapping/levels.py)
    consolidate_lr_scale: float = 1.0  # their learning rates: this x final_lr_scale x the lr_* above
    final_iterations_per_keyframe: int = 8  # finalize(): this x keyframes steps at the end (32 before #17)
    final_max_iterations: int = 2000  # finalize(): step cap (0: none); when it binds, worst keyframes first
    final_max_share: float = 0.0  # finalize(): at most this share of the run (0: off; timing-dependent)
    final_coarse_share: float = 0.5  # finalize(): its first share of steps at half resolution (#17; docs)
    final_lr_scale: float = 3.0  # finalize(): learning rates start at this x the lr_* above, decay to 10 %
    final_densify_rounds: int = (
        0  # finalize(): densify (error-based clone/split) this many times, evenly spaced
    )
    final_lambda_flow: float = 0.0  # finalize(): flow loss weight of the global pass (docs/mapping.md)
    final_pose_iterations: int = 0  # final joint pose+map refinement after finalize() (0: off; docs)
    final_lr_pose: float = 5e-4  # its Adam step of the keyframe se(3) deltas (decays to 10 %)
    final_pose_prior: float = 0.1  # its lambda_pose_prior (anchor to the graph poses)
    final_num_threads: int = 0  # after the frames: compositor threads (0: every core; torch keeps num_threads; docs)
    pose_window: int = 2  # newest keyframes of the window whose poses are refined jointly with the map
    lambda_pose_prior: float = 1.0  # anchors pose deltas to the given (graph) poses
    pose_prior_rel: float = 0.01  # prior std: rad, and this x median keyframe depth for translation
    pose_min_gain: float = 0.05  # pose-only refinement kept only if it lowers its loss by this fraction
    pose_init_prior: float = 1.0  # share of the pose prior used in that pose-only refinement
    registration_feedback: bool = False  # new keyframes registered against the converged map -> graph factors (mono runs; RGB-D: + the key below); off since session 11
    registration_feedback_rgbd: bool = False  # RGB-D runs register too (teddy 200 RGB-D: 0.91 -> 1.34 cm with it; docs/mapping.md)
    registration_iterations: int = 5  # robust Gauss-Newton steps of each registration
    registration_jacobian: str = "central"  # pose Jacobian: "central" differences (13 renders), "warp" of one render, "subpixel" (warp, exact slopes: 3)
    registration_min_coverage: float = 0.3  # fraction of the keyframe the map must cover (alpha > 0.9)
    registration_max_residual: float = 0.1  # largest robust colour residual spread at the optimum
    registration_min_information: float = 1000.0  # smallest eigenvalue, rad^-2 and (depth units)^-2
    registration_max_condition: float = 1e4  # largest condition number of that information
    registration_information_scale: float = 1e-3  # discount for correlated pixel and map errors (docs)
    registration_step_halvings: int = 2  # a Gauss-Newton step that does not lower the robust cost is halved this often (1 render each)
    registration_unconverged_weight: float = 0.0  # information share sent when Gauss-Newton did not reach the map's minimum (0: not sent; 1: session 9)
    registration_owner_split: float = 0.0  # relative: 0 = the largest owner carries it; > 0: every owner with this share or more, its share of the information
    registration_relative: bool = False  # a registration constrains the keyframe relative to the submap owning most of the converged map it saw (moves with loops; docs/mapping.md)
    feedback_min_age: int = 16  # keyframes: feedback only from Gaussians seeded this long ago (0: all; docs)
    feedback_min_converged: float = 0.5  # least share of a view's rendered weight from those Gaussians
    num_threads: int = (
        1  # torch CPU threads while the mapper works (0: leave torch's setting); docs/mapping.md
    )
    depth_confidence_weight: bool = False  # inverse-depth residuals x point-map confidence
    depth_scale_free: bool = False  # inverse-depth term x the keyframe's median depth (unit-free)


@dataclass(frozen=True)
class LoopConfig:
    enabled: bool = True
    skip_recent: int = 2  # submaps right before the current one are never loop candidates
    min_overlap: float = 0.3  # reprojection overlap ratio
    min_score: float = 0.5  # 0.7 * point overlap + 0.3 * appearance overlap
    min_inliers: int = 30
    inlier_threshold_m: float = 0.05  # RGB-D: 3D-3D RANSAC inlier distance (metres)
    max_candidates: int = 3
    inlier_threshold_rel: float = 0.02  # mono: inlier distance as a fraction of the median scene depth
    min_inlier_ratio: float = 0.25  # RANSAC inliers / matches needed to accept a loop
    ransac_iterations: int = 300
    depth_tolerance_rel: float = 0.2  # reprojected depth must agree with the view's depth within this
    max_view_angle_deg: float = 180.0  # overlap counts a point for a view pair only if their rays to it differ by <= this
    points_per_submap: int = 600  # subsampled points kept per submap for reprojection overlap
    orb_features: int = 400  # ORB keypoints per keyframe kept for verification
    max_reprojection_checks: int = 8  # candidates (by appearance) that get the reprojection test
    verify_view_pairs: int = 3  # best co-visible view pairs matched per candidate
    max_drift_ratio: float = 0.2  # loop vs current estimate: disagreement / path length between submaps
    max_rot_discrepancy_deg: float = 30.0  # loop vs current estimate, before and after optimisation
    max_residual_factor: float = 3.0  # after optimisation: loop residual RMS / inlier threshold
    rejoin_min_inliers: int = 12  # mono chains re-joined: inliers per submap pair and of the pooled Sim(3)
    rejoin_min_inlier_ratio: float = 0.08  # mono chains re-joined: inliers / matches per submap pair
    rejoin_min_fitness: float = 0.3  # mono chains re-joined: new points on the earlier surface after ICP
    mono_sigma_from_residual: bool = True  # mono: loop residual in submap units, sigma = the loop's inlier RMS (else graph.loop_sigma_m, world units)
    mono_sigma_min_rel: float = 0.25  # mono: floor of that sigma, as a fraction of the loop's inlier distance
    mono_sigma_ray: bool = True  # mono: loop noise along / across each point's viewing ray, from the loop's residuals (else one isotropic sigma)
    mono_dcs_phi: float = 1.0  # mono, ray noise: DCS kernel per loop, full weight up to chi2 = this x 3N (0: no kernel)
    mono_extent_sigma: float = 0.0  # mono: a loop's sigmas x max(1, this / its points' lateral extent, the 2nd principal std over median range; loop/extent.py); 0: off
    mono_inlier_gate: str = "median"  # mono RANSAC inliers (loop/ray_gate.py): "median" |T X_m - X_i| < inlier_threshold_rel x median depth; "range": < inlier_threshold_rel x the point's range; "ray": ray angle + range
    ray_threshold_deg: float = 1.0  # mono "ray" gate: angle between the two rays of a match, in submap i's view
    ray_depth_rel: float = 0.04  # mono "ray" gate: range disagreement / range (the point maps' depth noise)
    icp_refine: bool = False  # RGB-D: refine each loop by dense ICP of its closest keyframe pair; a relative-pose factor with the ICP information replaces its point factor (loop/icp_loop.py)
    icp_refine_pairs: int = 1  # RGB-D ICP loops: keyframe pairs aligned per loop (one per keyframe of the newer submap, closest first), fused into one relative pose (loop/icp_loop.py::fuse_pairs); 1: the closest pair only
    icp_loop_weight: float = 1.0  # RGB-D ICP loops (not the neighbour factors): their information x this (session 15: accurate loops pulled only halfway against the odometry)
    icp_effective_points: float = 100.0  # RGB-D ICP loops: the ICP Hessian of N matches is rescaled to this many independent matches
    icp_huber: float = 3.0  # RGB-D ICP loops: Huber threshold of the relative-pose factor (whitened units)
    icp_max_shift_m: float = 0.05  # RGB-D ICP loops: refused when ICP moves the loop's pose farther than this from RANSAC's
    icp_neighbours: int = 3  # RGB-D: ICP relative-pose factors from each new submap to its N predecessors (dense depth alignment next to the flow factors; with loop.enabled on or off; loop/icp_loop.py)
    icp_neighbour_floor_m: float = 0.0  # RGB-D neighbour ICP factors: covariance + this^2 on each translation axis (the encoders' local poses carry the pair to the submap frames; 0: off; session 9)
    icp_neighbour_floor_deg: float = 0.0  # ... and + this^2 on each rotation axis (deg)


@dataclass(frozen=True)
class PipelineConfig:
    track_points: int = 600  # flow matches per frame for tracking / PnP against the keyframe
    min_photo_consistency: float = 0.5  # fraction of matches whose warped grey value agrees
    min_pnp_inliers: int = 30
    min_pnp_inlier_ratio: float = 0.25
    pnp_threshold_px: float = 2.0
    blank_std: float = 0.01  # a frame whose intensity std is below this is blank (skipped)
    max_lost_frames: int = 2  # consecutive tracking failures that start a new submap chain
    cross_flow_back: int = 3  # each new keyframe gets flow to keyframes this far back in the previous submap
    flow_points: int = 1000  # correspondences per cross-submap keyframe pair
    max_time_gap_s: float = 0.5  # a longer gap between frames is an event; mono starts a new chain there
    pose_outlier_max_dev_m: float = 0.02  # non-keyframe this far (+ half its keyframes' gap) off their path: interpolated (0: off)
    pose_outlier_max_dev_deg: float = 3.0  # the same for the rotation (+ half the keyframes' rotation)
    pose_outlier_motion_check: bool = True  # ... unless it lies within pose_outlier_max_dev_m / _deg of the constant-velocity prediction from the two frames before it or the two after it (a curved path or a direction reversal, not a failed track; frontend/pose_outliers.py, docs/results.md session 12)
    track_icp: bool = False  # RGB-D: refine each tracked frame's PnP pose by ICP against its keyframe's depth
    track_icp_fallback: bool = True  # RGB-D: a frame whose PnP is refused even after a promoted keyframe (track_icp_promote_first) is tracked by ICP on depth (from the ungated PnP pose or a constant-velocity prediction) instead of failing (session 8: on; docs/results.md)
    track_icp_promote_first: bool = True  # RGB-D ICP fallback only where promoting the last tracked frame to a keyframe and retrying PnP cannot help (the retry, or no frame to promote): the keyframe set stays that of PnP tracking (false: ICP at once, session 7: +15 % on teddy200_fbf_7scenes loops on, docs/results.md)
    track_icp_min_fitness: float = 0.4  # RGB-D ICP fallback: ICP matched points / the frame's valid depth points (finest level) below this: failed (teddy, right poses: 0.49-0.63)
    track_joint_pose: bool = True  # RGB-D: each tracked frame's PnP pose re-solved from flow (PnP inliers) and depth (point-to-plane against its keyframe) jointly, as the keyframe poses (frontend/rgbd_tracking.py; docs/results.md, session 9)
    frame_pose_blend: bool = False  # RGB-D: a non-keyframe between keyframes A and B posed from both: T_w_A T_A_f and T_w_B inv(T_A_B) T_A_f (T_A_B: B tracked against A before it became a keyframe) blended by its time fraction between them, so graph corrections between A and B reach it in proportion (slam/poses.py::blend_between; docs/results.md, session 11)
    frame_pose_blend_gate_m: float = 0.02  # frame_pose_blend: an interval whose B track disagrees with the graph's A -> B by more than this is not blended (a failed track, not a correction)
    frame_pose_blend_gate_deg: float = 2.0  # the same for the rotation


@dataclass(frozen=True)
class RunConfig:
    checkpoint_every: int = 5  # submaps between checkpoints (docs/run_folders.md); 0: none, not on signals
    native_eval_keyframes: int = 12  # map PSNR/SSIM at the input resolution on at most this many keyframes, evenly spaced (0: none; docs/evaluation.md)
    native_eval_held_out: int = 12  # ... and on at most this many of the held-out frames, evenly spaced (0: none)
    trajectory_camera: str = "ground_truth"  # the camera trajectory.tum is: "ground_truth" (the one the dataset's ground truth poses: 7-Scenes' depth camera), "colour", "depth" (gsslam/run/trajectory_camera.py)
    trim_heap: bool = True  # after every new submap, hand the C heap's free pages back to the system (glibc malloc_trim; resident memory only, no result changes; docs/results.md, session 14)


@dataclass(frozen=True)
class ImuConfig:
    """Preintegrated IMU factors between keyframes (gsslam.slam.imu_stage); noise from EuRoC imu0/sensor.yaml."""

    enabled: bool = False  # --imu: CombinedImuFactor between consecutive keyframes (dataset must give IMU)
    gyro_noise_density: float = 1.6968e-4  # rad/s/sqrt(Hz), EuRoC imu0 gyroscope_noise_density
    gyro_random_walk: float = 1.9393e-5  # rad/s^2/sqrt(Hz), EuRoC imu0 gyroscope_random_walk
    accel_noise_density: float = 2.0e-3  # m/s^2/sqrt(Hz), EuRoC imu0 accelerometer_noise_density
    accel_random_walk: float = 3.0e-3  # m/s^3/sqrt(Hz), EuRoC imu0 accelerometer_random_walk
    gravity: float = 9.81  # m/s^2, magnitude; the graph world is z-up once the IMU is initialised
    static_window_s: float = 1.0  # IMU seconds before the first keyframe used for the static-start test
    static_max_accel_std: float = 0.15  # m/s^2: std of the window's 0.1 s accel means below this = static start (EuRoC V1_01 rest: <= 0.10; handheld teddy: >= 0.3)
    tie_rot_sigma: float = 0.005  # rad: keyframe body pose variable vs its submap's pose of the keyframe
    tie_trans_sigma: float = 0.005  # m at the submap's scale when the tie is made (tie in submap units)
    gravity_sigma: float = 0.02  # rad: prior on the world's roll/pitch after initialisation (IMU refines)
    accel_bias_sigma: float = 0.1  # m/s^2: prior on the first keyframe's accelerometer bias
    gyro_bias_sigma: float = 0.01  # rad/s: prior on the first keyframe's gyroscope bias
    min_init_keyframes: int = 4  # keyframes with IMU between them before the visual-inertial initialisation


@dataclass(frozen=True)
class Config:
    mode: str = "mono"  # "mono" | "rgbd"
    flow: FlowConfig = field(default_factory=FlowConfig)
    keyframes: KeyframeConfig = field(default_factory=KeyframeConfig)
    encoder: EncoderConfig = field(default_factory=EncoderConfig)
    graph: GraphConfig = field(default_factory=GraphConfig)
    mapper: MapperConfig = field(default_factory=MapperConfig)
    loop: LoopConfig = field(default_factory=LoopConfig)
    pipeline: PipelineConfig = field(default_factory=PipelineConfig)
    run: RunConfig = field(default_factory=RunConfig)
    imu: ImuConfig = field(default_factory=ImuConfig)
    seed: int = 0
