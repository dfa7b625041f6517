"""Frame tracking against the latest keyframe: flow matches, PnP, health checks.

Every incoming frame is matched to the current reference keyframe with one dense flow
(``flow(ref, frame)``); the same flow drives keyframe selection. Non-keyframes get their pose
relative to the reference keyframe by PnP on those matches, lifted to 3D with the keyframe's
depth: the sensor depth in an RGB-D run (solved at once), or the keyframe's point-map depth
from its submap encoding in a monocular run (solved when that submap is encoded; the
translation is then in the submap's units and is scaled to world units by the pipeline).

Health checks on every frame: a blank image (almost no intensity variation), a flow whose
warped colours do not match (a jump, a cut, a flow failure), or a PnP with too few inliers are
reported as tracking loss; the pipeline records the event and starts a new submap chain.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np

from gsslam.errors import GsslamError
from gsslam.frontend.pose_estimation import pnp
from gsslam.geometry import backproject, interpolate_pose
from gsslam.types import CameraIntrinsics, Frame

log = logging.getLogger(__name__)


class TrackingError(GsslamError):
    """Tracking inputs are inconsistent (e.g. sizes of a frame and its keyframe differ)."""


@dataclass
class FrameMatches:
    """Flow matches from a reference keyframe to a frame: ``uv_ref``, ``uv_cur`` [N, 2] full-res pixels."""

    ref_index: int
    cur_index: int
    uv_ref: np.ndarray
    uv_cur: np.ndarray


@dataclass
class TrackStatus:
    ok: bool
    reason: str = ""  # "blank" | "flow" | "pnp" when not ok
    photo_consistency: float = 1.0  # fraction of matches whose warped colour agrees
    median_flow_px: float = 0.0


_GRAY_WEIGHTS = np.array([0.299, 0.587, 0.114], dtype=np.float32)  # as Frame.gray


def is_blank(frame: Frame, min_std: float) -> bool:
    """A frame with almost no intensity variation (black, white, lens cap)."""
    g = frame.image[::4, ::4] @ _GRAY_WEIGHTS  # grey of the sampled pixels only
    return float(np.std(g)) < min_std


def grid_flow_matches(
    ref: Frame,
    cur: Frame,
    flow: np.ndarray,  # [H, W, 2] ref -> cur
    n_points: int,
    depth_ref: np.ndarray | None = None,  # [H, W]; when given, only pixels with valid depth
    border: int = 8,
) -> FrameMatches:
    """Matches on a regular grid of ``ref`` pixels whose flow target lands inside ``cur``.

    A grid (not random pixels, as :func:`gsslam.frontend.pose_estimation.random_flow_matches`) spreads
    the matches evenly for the health checks and PnP of every frame.
    """
    h, w = flow.shape[:2]
    step = max(2, int(np.sqrt((h - 2 * border) * (w - 2 * border) / max(n_points, 1))))
    vv, uu = np.mgrid[border : h - border : step, border : w - border : step]
    uu, vv = uu.ravel(), vv.ravel()
    keep = np.ones(len(uu), bool)
    if depth_ref is not None:
        d = depth_ref[vv, uu]
        keep &= np.isfinite(d) & (d > 0)
    f = flow[vv, uu]
    tu, tv = uu + f[:, 0], vv + f[:, 1]
    keep &= (tu >= 0) & (tu <= w - 1) & (tv >= 0) & (tv <= h - 1) & np.all(np.isfinite(f), axis=1)
    uv_ref = np.stack([uu[keep], vv[keep]], axis=1).astype(np.float64)
    uv_cur = np.stack([tu[keep], tv[keep]], axis=1).astype(np.float64)
    return FrameMatches(ref.index, cur.index, uv_ref, uv_cur)


def photo_consistency(ref: Frame, cur: Frame, m: FrameMatches, threshold: float = 0.08) -> float:
    """Fraction of matches whose grey value in ``cur`` (bilinear at uv_cur) agrees with ``ref``."""
    if len(m.uv_ref) == 0:
        return 0.0
    # grey values at the matches only (no full-image conversion): colour sampled, then weighted
    a = ref.image[m.uv_ref[:, 1].astype(int), m.uv_ref[:, 0].astype(int)] @ _GRAY_WEIGHTS
    b = (
        cv2.remap(
            np.ascontiguousarray(cur.image, dtype=np.float32),
            m.uv_cur[:, 0].astype(np.float32).reshape(-1, 1),
            m.uv_cur[:, 1].astype(np.float32).reshape(-1, 1),
            cv2.INTER_LINEAR,
        ).reshape(-1, 3)
        @ _GRAY_WEIGHTS
    )
    return float(np.mean(np.abs(a - b) < threshold))


def sample_depth(
    depth: np.ndarray,  # [h, w] at the resolution of ``depth_intrinsics``
    depth_intrinsics: CameraIntrinsics,
    full: CameraIntrinsics,
    uv: np.ndarray,  # [N, 2] full-resolution pixels
) -> np.ndarray:  # [N] (NaN where unknown)
    """Nearest-neighbour depth lookup of full-resolution pixels in a (possibly smaller) depth map."""
    sx, sy = depth_intrinsics.width / full.width, depth_intrinsics.height / full.height
    u = np.clip(np.round((uv[:, 0] + 0.5) * sx - 0.5).astype(int), 0, depth.shape[1] - 1)
    v = np.clip(np.round((uv[:, 1] + 0.5) * sy - 0.5).astype(int), 0, depth.shape[0] - 1)
    d = depth[v, u].astype(np.float64)
    d[~(d > 0)] = np.nan
    return d


def solve_relative_pose(
    m: FrameMatches,
    depth_ref: np.ndarray,  # [N] depth (z) of uv_ref in the reference camera, NaN unknown
    K: np.ndarray,  # [3, 3]
    min_inliers: int,
    min_inlier_ratio: float,
    threshold_px: float = 2.0,
) -> tuple[np.ndarray | None, int]:
    """``T_ref_cur`` [4, 4] by PnP RANSAC + LM refinement, or ``(None, inliers)`` when unreliable.

    One RANSAC (100 iterations) and one refinement on its inliers, cheap enough for every frame:
    :func:`~gsslam.frontend.pose_estimation.pnp` with ``reselect=False``.
    """
    ok = np.isfinite(depth_ref) & (depth_ref > 0)
    uv_ref, z = m.uv_ref[ok], depth_ref[ok]
    X = backproject(K, uv_ref, z)
    res = pnp(
        X,
        m.uv_cur[ok],
        K,
        threshold_px,
        min_inliers,
        iterations=100,
        min_inlier_ratio=min_inlier_ratio,
        reselect=False,
    )
    if res.T_tgt_src is None:
        return None, res.inliers
    R_cur_ref, t_cur_ref = res.T_tgt_src[:3, :3], res.T_tgt_src[:3, 3]
    T_ref_cur = np.eye(4)
    T_ref_cur[:3, :3] = R_cur_ref.T
    T_ref_cur[:3, 3] = -R_cur_ref.T @ t_cur_ref
    return T_ref_cur, res.inliers


class FrameTracker:
    """Matches each frame to the current reference keyframe and checks tracking health."""

    def __init__(
        self, flow, n_points: int, min_photo_consistency: float, blank_std: float, use_depth: bool = True
    ) -> None:
        self.flow = flow
        self.use_depth = use_depth
        self.n_points = n_points
        self.min_photo_consistency = min_photo_consistency
        self.blank_std = blank_std
        self.ref: Frame | None = None

    def set_reference(self, frame: Frame) -> None:
        self.ref = frame

    def track(self, frame: Frame) -> tuple[np.ndarray | None, FrameMatches | None, TrackStatus]:
        """-> (flow ref->frame [H, W, 2], matches, status). Needs a reference keyframe."""
        if self.ref is None:
            raise TrackingError("no reference keyframe: call set_reference first")
        if frame.image.shape != self.ref.image.shape:
            raise TrackingError(
                f"frame {frame.index} is {frame.image.shape}, keyframe is {self.ref.image.shape}"
            )
        if is_blank(frame, self.blank_std):
            return None, None, TrackStatus(False, "blank")
        flow = self.flow(self.ref.image, frame.image)
        depth = self.ref.depth if self.use_depth else None
        m = grid_flow_matches(self.ref, frame, flow, self.n_points, depth_ref=depth)
        pc = photo_consistency(self.ref, frame, m)
        med = float(np.median(np.hypot(flow[::8, ::8, 0], flow[::8, ::8, 1])))
        if pc < self.min_photo_consistency or len(m.uv_ref) < 20:
            return flow, m, TrackStatus(False, "flow", pc, med)
        return flow, m, TrackStatus(True, "", pc, med)


def interpolate_poses(
    poses: dict[int, np.ndarray],  # frame index -> T_world_cam [4, 4] (known poses)
    wanted: list[int],  # frames that should get a pose
    timestamps: dict[int, float],  # frame index -> seconds
) -> dict[int, np.ndarray]:
    """Poses of ``wanted`` frames missing from ``poses``, interpolated in time between the nearest
    posed frames before and after (linear translation, geodesic rotation); frames outside the posed
    time span get none (no extrapolation). The fallback when PnP of a tracked frame fails."""
    known = sorted((timestamps[i], i) for i in poses if i in timestamps)
    if len(known) < 2:
        return {}
    kt = np.array([t for t, _ in known])
    out = {}
    for i in wanted:
        if i in poses or i not in timestamps:
            continue
        t = timestamps[i]
        k = int(np.searchsorted(kt, t))
        if k == 0 or k == len(kt):
            continue
        (ta, a), (tb, b) = known[k - 1], known[k]
        u = 0.0 if tb == ta else (t - ta) / (tb - ta)
        out[i] = interpolate_pose(poses[a], poses[b], u)
    return out
