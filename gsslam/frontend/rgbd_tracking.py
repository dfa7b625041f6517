"""RGB-D frame tracking: PnP on the flow matches, point-to-plane ICP on depth where PnP is refused.

A frame's pose relative to its keyframe comes from PnP on the colour-flow matches lifted with the
keyframe's depth (:func:`gsslam.frontend.tracking.solve_relative_pose`). Under motion blur and a quick
hand (teddy played 2x faster with a half-frame shutter: 5-12 cm and 4-9 deg between keyframe and
frame) the dense flow loses precision before it loses the scene: 10-25 % of the matches lie within
2 px of the best PnP pose, PnP is refused by its inlier-ratio gate (0.25) and the keyframe is
promoted (docs/results.md, "RGB-D tracking under blur, session 7"). The depth images do not blur:
dense point-to-plane ICP of the two depth maps (:mod:`gsslam.frontend.icp`), started from the refused
PnP pose (its inlier-ratio gate lifted) or from a constant-velocity prediction, recovers those poses
to 0.2-0.5 cm where PnP was 1.3-7.5 cm off.

:func:`track_relative_pose` is the RGB-D tracking step; :class:`MotionPrior` keeps the last two
tracked poses for the constant-velocity prediction. ICP runs at :func:`track_strides` (the strides of
``pipeline.track_icp`` at 640x480).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gsslam.frontend.icp import TRACK_STRIDES, icp_point_to_plane, refine_relative_pose
from gsslam.frontend.joint_pose import joint_pose
from gsslam.frontend.tracking import FrameMatches, solve_relative_pose
from gsslam.geometry import backproject, interpolate_pose, invert_T
from gsslam.types import CameraIntrinsics


@dataclass(frozen=True)
class TrackParams:
    """The gates of one RGB-D tracking step (from ``PipelineConfig``)."""

    min_inliers: int = 30  # PnP inliers (also for the relaxed PnP that starts ICP)
    min_inlier_ratio: float = 0.25  # PnP inliers / matches below this: PnP is refused
    threshold_px: float = 2.0  # PnP inlier threshold
    refine_icp: bool = False  # refine every accepted PnP pose by ICP as well (pipeline.track_icp)
    icp_fallback: bool = False  # a refused PnP: ICP from the relaxed PnP pose / the prediction
    icp_min_fitness: float = 0.4  # ICP matched points / valid source points at the finest level
    joint: bool = False  # an accepted PnP pose re-solved from flow and depth jointly (track_joint_pose)


@dataclass(frozen=True)
class RgbdTrack:
    T_ref_cur: np.ndarray | None  # [4, 4]; None: tracking failed
    # "pnp" | "pnp+joint" | "pnp+icp" (pipeline.track_icp) | "icp" (after a refused PnP) | "" (failed)
    source: str
    pnp_inliers: int
    pnp_matches: int
    icp_fitness: float = float("nan")  # of the ICP that gave the pose (NaN: none)


def track_strides(width: int) -> tuple[int, int]:
    """ICP strides for a depth map ``width`` px wide: :data:`TRACK_STRIDES` at 640 px, scaled with it
    (80x60 points at the finest level, whatever the resolution)."""
    s = max(1, round(width * TRACK_STRIDES[-1] / 640))
    return (2 * s, s)


def icp_fitness(depth_src: np.ndarray, inliers: int, stride: int) -> float:
    """ICP matched points / valid source points sampled every ``stride`` px (ICP's finest level)."""
    d = depth_src[stride // 2 :: stride, stride // 2 :: stride]
    n = int(np.count_nonzero(d > 0))
    return inliers / n if n else 0.0


def _icp(depth_ref, depth_cur, intr, T_ref_cur) -> tuple[np.ndarray | None, float]:
    """ICP of the current depth onto the keyframe's from ``T_ref_cur``: (T_ref_cur or None, fitness)."""
    strides = track_strides(depth_cur.shape[1])
    res = icp_point_to_plane(depth_ref, depth_cur, intr, invert_T(T_ref_cur), strides=strides)
    if not res.ok:
        return None, 0.0
    return invert_T(res.T_tgt_src), icp_fitness(depth_cur, res.inliers, strides[-1])


def joint_strides(width: int) -> tuple[int, int]:
    """Strides of the joint flow + depth pose of a tracked frame: half :func:`track_strides` (80x60 then
    160x120 points at 640 px, the keyframe pairs' point count)."""
    s = max(1, round(width * TRACK_STRIDES[-1] / 640 / 2))
    return (2 * s, s)


def _joint(matches, z_ref, depth_ref, depth_cur, intr, T_ref_cur, threshold_px) -> np.ndarray | None:
    """Flow (the matches within ``threshold_px`` of the PnP pose) and depth jointly from ``T_ref_cur``:
    the refined ``T_ref_cur``, or None when the solve refuses (:mod:`gsslam.frontend.joint_pose`)."""
    ok = np.isfinite(z_ref) & (z_ref > 0)
    K = intr.K
    uv, z = matches.uv_ref[ok], z_ref[ok]
    X = backproject(K, uv, z)
    res = joint_pose(
        X, matches.uv_cur[ok], depth_ref, depth_cur, intr, invert_T(T_ref_cur),
        strides=joint_strides(depth_cur.shape[1]), inlier_px=threshold_px,
    )  # fmt: skip
    return invert_T(res.T_tgt_src) if res.ok else None


def track_relative_pose(
    matches: FrameMatches,
    z_ref: np.ndarray,  # [N] keyframe depth at matches.uv_ref (NaN unknown)
    depth_ref: np.ndarray,  # [H, W] metres, the keyframe
    depth_cur: np.ndarray | None,  # [H, W] metres, the frame
    intr: CameraIntrinsics,  # of the images and depth maps
    params: TrackParams,
    T_pred: np.ndarray | None = None,  # [4, 4] predicted T_ref_cur (constant velocity), optional
) -> RgbdTrack:
    """``T_ref_cur`` of a frame: PnP (then flow + depth jointly with ``joint``, where that solve accepts),
    else (``icp_fallback``) ICP from the best start (module docstring)."""
    K = intr.K
    n = int(np.count_nonzero(np.isfinite(z_ref) & (z_ref > 0)))
    T, inl = solve_relative_pose(
        matches, z_ref, K, params.min_inliers, params.min_inlier_ratio, params.threshold_px
    )
    if T is not None:
        if params.joint and depth_cur is not None:
            T_joint = _joint(matches, z_ref, depth_ref, depth_cur, intr, T, params.threshold_px)
            if T_joint is not None:
                return RgbdTrack(T_joint, "pnp+joint", inl, n)
        if params.refine_icp and depth_cur is not None:  # pipeline.track_icp: ICP at TRACK_STRIDES, as before
            return RgbdTrack(refine_relative_pose(depth_ref, depth_cur, intr, T), "pnp+icp", inl, n)
        return RgbdTrack(T, "pnp", inl, n)
    if not params.icp_fallback or depth_cur is None:
        return RgbdTrack(None, "", inl, n)
    starts = []
    if params.min_inlier_ratio > 0:  # the same PnP without its ratio gate
        T_relaxed, _ = solve_relative_pose(matches, z_ref, K, params.min_inliers, 0.0, params.threshold_px)
        if T_relaxed is not None:
            starts.append(T_relaxed)
    if T_pred is not None:
        starts.append(T_pred)
    best, best_fit = None, params.icp_min_fitness
    for T0 in starts:
        T_icp, fit = _icp(depth_ref, depth_cur, intr, T0)
        if T_icp is not None and fit >= best_fit:
            best, best_fit = T_icp, fit
    if best is None:
        return RgbdTrack(None, "", inl, n)
    return RgbdTrack(best, "icp", inl, n, best_fit)


class MotionPrior:
    """The last two tracked poses (by frame index): a constant-velocity prediction of the next one."""

    def __init__(self) -> None:
        self._last: list[tuple[int, np.ndarray]] = []  # at most two (index, T_world_cam), older first

    def observe(self, index: int, T_world_cam: np.ndarray) -> None:
        if self._last and self._last[-1][0] == index:
            self._last[-1] = (index, T_world_cam.copy())  # the same frame re-posed (a new keyframe)
            return
        self._last = [*self._last[-1:], (index, T_world_cam.copy())]

    def reset(self) -> None:
        self._last = []

    def predict(self, index: int) -> np.ndarray | None:
        """``T_world_cam`` of frame ``index`` extrapolated at constant velocity (None: too few poses)."""
        if len(self._last) < 2:
            return None
        (i0, A), (i1, B) = self._last
        if not (i0 < i1 < index):
            return None
        return interpolate_pose(A, B, (index - i0) / (i1 - i0))
