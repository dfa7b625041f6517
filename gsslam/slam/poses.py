"""Poses of a pipeline's frames, read from its chains' graphs (nothing here changes the pipeline).

A keyframe's pose is its graph's estimate; a non-keyframe's is its tracked pose relative to its
keyframe (PnP on the keyframe's depth: sensor depth in RGB-D, the submap's point map in mono) composed
with the keyframe's pose; a frame whose PnP fails, or whose pose leaves its keyframes' path, is
interpolated in time (unless it follows the motion of the frames around it: a curved path, not a failed
track; ``pipeline.pose_outlier_motion_check``). With ``pipeline.frame_pose_blend`` (RGB-D) a non-keyframe
between keyframes A and B is posed from both (:func:`blend_between`). ``p`` is a
:class:`gsslam.slam.pipeline.Pipeline`; these functions read its public state (``cfg``, ``intrinsics``,
``monocular``, ``chains``, ``keyframes``, ``relative``, ``keyframe_relative``, ``pending``, ``window``,
``timestamps``, ``online_poses``).
"""

from __future__ import annotations

import bisect
import logging

import numpy as np

from gsslam.errors import GsslamError
from gsslam.frontend.tracking import FrameMatches, interpolate_poses, sample_depth, solve_relative_pose
from gsslam.geometry import interpolate_pose, invert_T, sim3_scale, so3_log

log = logging.getLogger(__name__)


def relative_pnp(p, matches: FrameMatches, depth: np.ndarray) -> np.ndarray | None:
    """``T_ref_cur`` [4, 4] by PnP of the flow matches on the reference depth [N] (None: failed)."""
    pc = p.cfg.pipeline
    K = p.intrinsics.K
    T, _ = solve_relative_pose(
        matches, depth, K, pc.min_pnp_inliers, pc.min_pnp_inlier_ratio, pc.pnp_threshold_px
    )
    return T


def relative_rgbd(p, frame, matches: FrameMatches, depth_ref: np.ndarray, fallback: bool = True):
    """RGB-D ``T_ref_cur`` of ``frame`` by PnP on the flow matches, ICP on depth where PnP is refused
    (:func:`gsslam.frontend.rgbd_tracking.track_relative_pose`; ``.T_ref_cur`` None: failed).
    ``fallback=False``: no ICP fallback for this attempt (the pipeline promotes a keyframe first)."""
    from gsslam.frontend.rgbd_tracking import TrackParams, track_relative_pose

    pc = p.cfg.pipeline
    use_icp = getattr(p.encoder, "use_icp", False)
    check = getattr(p.encoder, "check", None)  # the encoder's ColourDepthCheck: ICP where colour disagrees
    # joint flow + depth poses where the encoder takes them (its rule, encoder.rgbd_joint_with_icp)
    mismatch = check is not None and check.mismatch
    joint_ok = not use_icp or (p.cfg.encoder.rgbd_joint_with_icp and not mismatch)
    params = TrackParams(
        pc.min_pnp_inliers,
        pc.min_pnp_inlier_ratio,
        pc.pnp_threshold_px,
        refine_icp=pc.track_icp or use_icp,
        icp_fallback=pc.track_icp_fallback and fallback,
        icp_min_fitness=pc.track_icp_min_fitness,
        joint=pc.track_joint_pose and joint_ok,
    )
    T_pred = None
    if params.icp_fallback:  # the constant-velocity start is read only by the ICP fallback
        T_world_ref = pose_now(p, matches.ref_index)
        T_world_pred = p.motion.predict(frame.index)
        if T_world_ref is not None and T_world_pred is not None:
            T_pred = np.linalg.inv(T_world_ref) @ T_world_pred
    z = sample_depth(depth_ref, p.intrinsics, p.intrinsics, matches.uv_ref)
    return track_relative_pose(matches, z, depth_ref, frame.depth, p.intrinsics, params, T_pred)


def to_world_units(p, ref: int, T_ref_cur: np.ndarray) -> np.ndarray:
    """Scale a relative pose measured in the keyframe's submap units to world units."""
    kf = p.keyframes.get(ref)
    if kf is None or not p.monocular:
        return T_ref_cur
    chain = p.chains[kf.chain]
    s = chain.scale * sim3_scale(chain.graph.submap_pose(kf.submap))
    T = T_ref_cur.copy()
    T[:3, 3] *= s
    return T


def pose_now(p, index: int) -> np.ndarray | None:
    """Current ``T_world_cam`` of a keyframe: the graph's estimate, else its pose as it arrived."""
    kf = p.keyframes.get(index)
    if kf is not None and not p.chains[kf.chain].failed:
        chain = p.chains[kf.chain]
        try:
            return chain.world_pose(chain.keyframe_pose(index))
        except GsslamError:
            pass
    return p.online_poses.get(index)


def tracked_pose(p, matches: FrameMatches, T_ref_cur: np.ndarray | None) -> np.ndarray | None:
    """The frame's pose from its match to the reference keyframe (RGB-D: PnP already solved)."""
    ref = matches.ref_index
    T_world_ref = pose_now(p, ref)
    if T_world_ref is None:
        return None
    if T_ref_cur is None:  # mono: PnP against the keyframe's point-map depth, once it has one
        kf = p.keyframes.get(ref)
        if kf is None:
            return None
        intr = p.chains[kf.chain].encodings[kf.submap].intrinsics
        depth = sample_depth(kf.depth, intr, p.intrinsics, matches.uv_ref)
        T_ref_cur = relative_pnp(p, matches, depth)
        if T_ref_cur is None:
            return None
    return T_world_ref @ to_world_units(p, ref, T_ref_cur)


def keyframe_poses(p) -> dict[int, np.ndarray]:
    """``T_world_cam`` [4, 4] of every keyframe the graphs know (current estimates)."""
    out = {}
    for idx, kf in p.keyframes.items():
        chain = p.chains[kf.chain]
        try:
            out[idx] = chain.world_pose(chain.keyframe_pose(idx))
        except GsslamError as e:
            log.warning("keyframe %d has no pose: %s", idx, e)
    for chain in p.chains:  # a chain that never got a submap: its origin keyframe only
        if not chain.encodings and p.window and chain is p.chains[-1]:
            out.setdefault(p.window[0].index, chain.T_world_chain.copy())
    return out


def blend_between(
    kf_poses: dict[int, np.ndarray],  # keyframe -> T_world_cam [4, 4] (final estimates)
    relative: dict[int, tuple[int, np.ndarray]],  # non-keyframe f -> (keyframe A, tracked T_A_f [4, 4])
    keyframe_relative: dict[int, tuple[int, np.ndarray]],  # keyframe B -> (keyframe A, tracked T_A_B)
    timestamps: dict[int, float],  # frame -> seconds
    gate_m: float = 0.02,
    gate_deg: float = 2.0,
) -> dict[int, np.ndarray]:
    """``T_world_cam`` of each non-keyframe f posed from both keyframes around it.

    f was tracked against A (``T_A_f``) and so was the next keyframe B before it became one (``T_A_B``).
    From A, ``T_w_A T_A_f``; from B, ``T_w_B inv(T_A_B) T_A_f``: the two differ by the graph's correction
    of A -> B against tracking. f gets the pose the fraction u = (t_f - t_A) / (t_B - t_A) of the way
    from the first to the second (geodesic rotation, linear translation), so a correction that the graph
    (loops) makes between A and B reaches the frames between it in proportion, not only through A.
    Frames whose next keyframe was not tracked against A (a new chain, a gap) are left out, and so are
    those whose B track disagrees with the graph's A -> B by more than ``gate_m`` / ``gate_deg`` (a failed
    track, not a correction: one on teddy200_s3_blur_rgbd was 13.7 cm off)."""
    kfs = sorted(kf_poses)
    out = {}
    for f, (a, T_a_f) in relative.items():
        k = bisect.bisect_left(kfs, f)
        if k == 0 or k == len(kfs) or kfs[k - 1] != a:
            continue
        b = kfs[k]
        if keyframe_relative.get(b, (None,))[0] != a:
            continue
        D = invert_T(invert_T(kf_poses[a]) @ kf_poses[b]) @ keyframe_relative[b][1]  # graph vs track at B
        if np.linalg.norm(D[:3, 3]) > gate_m or np.degrees(np.linalg.norm(so3_log(D[:3, :3]))) > gate_deg:
            continue
        t_a, t_b = timestamps[a], timestamps[b]
        u = 0.5 if t_b <= t_a else min(max((timestamps[f] - t_a) / (t_b - t_a), 0.0), 1.0)
        from_a = kf_poses[a] @ T_a_f
        from_b = kf_poses[b] @ invert_T(keyframe_relative[b][1]) @ T_a_f
        out[f] = interpolate_pose(from_a, from_b, u)
    return out


def frame_poses(p) -> tuple[dict[int, np.ndarray], int | None]:
    """``(T_world_cam of every frame that has one, number of pose outliers replaced)``: keyframes, then
    non-keyframes via their keyframe. The count is None when the outlier check is off."""
    kf_poses = keyframe_poses(p)
    out = dict(kf_poses)
    for idx, (ref, T_ref_cur) in p.relative.items():
        if ref in kf_poses:
            out[idx] = kf_poses[ref] @ to_world_units(p, ref, T_ref_cur)
    pc = p.cfg.pipeline
    if pc.frame_pose_blend and not p.monocular:  # from both neighbouring keyframes
        gate = (pc.frame_pose_blend_gate_m, pc.frame_pose_blend_gate_deg)
        out.update(blend_between(kf_poses, p.relative, p.keyframe_relative, p.timestamps, *gate))
    for m, _cid in p.pending:
        if m.ref_index not in kf_poses or m.ref_index not in p.keyframes:
            continue
        kf = p.keyframes[m.ref_index]
        intr = p.chains[kf.chain].encodings[kf.submap].intrinsics
        depth = sample_depth(kf.depth, intr, p.intrinsics, m.uv_ref)
        T = relative_pnp(p, m, depth)
        if T is not None:
            out[m.cur_index] = kf_poses[m.ref_index] @ to_world_units(p, m.ref_index, T)
    # a tracked frame whose PnP failed (or whose keyframe has no depth) is interpolated in time
    out.update(interpolate_poses(out, [m.cur_index for m, _ in p.pending], p.timestamps))
    n_outliers = None
    if pc.pose_outlier_max_dev_m > 0:  # and so is one whose PnP pose leaves its keyframes' path
        from gsslam.frontend.pose_outliers import find_pose_outliers

        bad = find_pose_outliers(
            out,
            set(kf_poses),
            p.timestamps,
            pc.pose_outlier_max_dev_m,
            pc.pose_outlier_max_dev_deg,
            motion_check=pc.pose_outlier_motion_check,
        )
        for f in bad:
            out.pop(f)
        out.update(interpolate_poses(out, bad, p.timestamps))
        n_outliers = len(bad)
    return dict(sorted(out.items())), n_outliers


def frame_chains(p) -> dict[int, int]:
    """The chain of every frame that can have a pose: its keyframe's chain (or the tracked chain)."""
    out = {idx: kf.chain for idx, kf in p.keyframes.items()}
    for idx, (ref, _T) in p.relative.items():
        if ref in p.keyframes:
            out[idx] = p.keyframes[ref].chain
    for m, cid in p.pending:
        out[m.cur_index] = cid
    if p.window and p.chains:  # the origin of a chain that has no submap yet
        out.setdefault(p.window[0].index, len(p.chains) - 1)
    return out
