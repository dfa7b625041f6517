"""Focal length self-calibration for monocular runs: the focal whose bundle adjustments explain the flow best.

A 7-Scenes-like loader hands out the depth camera's intrinsics (fx = fy = 585) with colour images of a
~525 px camera; a mono run has no depth to check them against (RGB-D: ``frontend/colour_focal.py``).
With a focal length ``s`` times too long every rotation and lateral motion comes out ~``1/s`` too small
and the structure is distorted: no later stage can repair that.

Observability: over several views of a rigid scene, a wrong focal length leaves a reprojection residual
that no poses and depths can absorb (the image of a rotation ``K R K^-1`` is not a homography of that
form at another focal; with translation the depths must also stay positive and shared by all views of a
track). Near-critical motions leave the focal unobservable: pure translation, and an orbit whose optical
axes all meet in one point (TUM teddy, the synthetic ``loop``); a room scan that pans is not one.

The estimate (deterministic):

1. Windows of ``window`` frames ``gap`` apart from the first frames, at the point-map resolution;
   tracks from the window's first frame, chained through consecutive flows and checked forward-backward
   (textured pixels only, ``max_points`` sampled).
2. For each window at the given focal: two-view pose (essential matrix) to the farthest frame with
   enough parallax, triangulation, PnP for the others; without two-view geometry (a pan, little
   parallax) rotations from homographies and no translation; then the local BA
   (``two_view.bundle_adjust``). Windows with too few tracks or no homography are left out.
3. The profile: for each focal scale on a grid (``scales``, outwards from a start scale with the previous
   BA as the start, so the profile is continuous), the BA at that focal and the Cauchy cost of all tracks
   at its poses (``mono_init.track_cost``). Step 2 and the sweep are repeated from each of ``starts``
   (1, 0.9 and 1.1: the two-view pose at that focal) and the lowest cost per scale is kept: a focal 11 %
   too long turns a lateral translation into rotation (the two-view pose is 20-40 deg off) and a BA
   started there can stay in that basin, its minimum on the wrong side of 1 (the long synthetic room,
   docs/results.md session 13). Summed over windows; the estimate is the grid minimum refined by a
   parabola.
4. The confidence: the windows vote too (each window's own minimum); the estimate is ``ok`` when the
   minimum is inside the grid, enough windows took part, the summed cost at the estimate is lower than
   at the given focal by ``min_gain`` (relative), and most windows agree with it within ``agree``.

:func:`mono_focal_correction` decides (``ok`` and more than ``encoder.mono_focal_min_dev`` from 1);
:func:`rescale_focal` hands out a frame with the corrected intrinsics (``run/sequence.py``, with
``encoder.mono_focal_auto``; off by default, docs/results.md "Mono focal length, session 10").
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np

from gsslam.config import EncoderConfig
from gsslam.frontend.colour_focal import parabola_min
from gsslam.frontend.encoder import pointmap_intrinsics, resize_image
from gsslam.frontend.flow import FlowEstimator, chained_flows
from gsslam.frontend.mono_init import track_cost
from gsslam.frontend.pose_estimation import pnp, random_flow_matches
from gsslam.frontend.two_view import bundle_adjust, rotation_from_homography, triangulate_rays, two_view_pose
from gsslam.types import CameraIntrinsics, Frame

log = logging.getLogger(__name__)

FB_THRESHOLD_PX = 1.0  # forward-backward check of the chained tracks (point-map pixels)
THRESHOLD_PX = 1.0  # Huber (BA) and Cauchy (cost) kernel, point-map pixels
MIN_TRACKS = 60
MIN_PARALLAX_DEG = 1.0
DEFAULT_SCALES = np.round(np.arange(0.80, 1.2001, 0.02), 4)  # focal scales tried (estimated / given)
DEFAULT_STARTS = (1.0, 0.9, 1.1)  # focal scales each window's poses are initialised at (window_profile)


@dataclass(frozen=True)
class MonoFocalEstimate:
    scale: float  # estimated focal / given focal (1: the given intrinsics fit)
    windows: int  # windows that took part
    tracks: int  # tracks over all windows
    cost_given: float  # summed Cauchy cost (px^2) at scale 1
    cost_best: float  # at the grid minimum
    window_scales: tuple[float, ...]  # each window's own minimum
    agreeing: int  # windows whose minimum is within the agreement band of the estimate
    ok: bool  # minimum inside the grid, enough windows, gain and agreement (module doc)

    @property
    def gain(self) -> float:  # relative cost drop from the given focal to the estimate
        return 0.0 if not self.cost_given > 0 else 1.0 - self.cost_best / self.cost_given


@dataclass
class TrackWindow:
    uv0: np.ndarray  # [N, 2] track pixels in the window's first frame
    obs: np.ndarray  # [W, N, 2] their pixels in every frame (NaN where not valid; row 0 unused)


def window_tracks(imgs: list[np.ndarray], flow: FlowEstimator, max_points: int, rng) -> TrackWindow:
    """Tracks from frame 0 of ``imgs`` chained through consecutive flows, checked forward-backward."""
    n = len(imgs)
    w = imgs[0].shape[1]
    fws, _, valids = chained_flows(imgs, flow, FB_THRESHOLD_PX)
    uv0, _, _ = random_flow_matches(fws[1], valids[1], None, max_points, rng)
    ui = np.round(uv0).astype(int)
    lin = ui[:, 1] * w + ui[:, 0]
    obs = np.full((n, len(uv0), 2), np.nan)
    for i in range(1, n):
        ok = valids[i].reshape(-1)[lin]
        obs[i, ok] = uv0[ok] + fws[i].reshape(-1, 2)[lin[ok]]
    return TrackWindow(uv0, obs)


def _init_poses(K: np.ndarray, win: TrackWindow):  # -> (T_i_0 [W, 4, 4], rho [N], tracks mask [N]) or None
    """Two-view pose to the farthest frame with geometry, triangulation, PnP for the others."""
    n = len(win.obs)
    for r in range(n - 1, 0, -1):
        ok = np.isfinite(win.obs[r]).all(1)
        if ok.sum() < MIN_TRACKS:
            continue
        tv = two_view_pose(K, win.uv0[ok], win.obs[r, ok], THRESHOLD_PX, MIN_TRACKS, MIN_PARALLAX_DEG)
        if tv.T_b_a is None:
            continue
        X, _, _ = triangulate_rays(K, win.uv0[ok], win.obs[r, ok], tv.T_b_a)
        keep = np.isfinite(X).all(1) & (X[:, 2] > 0)
        if keep.sum() < MIN_TRACKS:
            continue
        idx = np.flatnonzero(ok)[keep]
        X = X[keep]
        T = _pnp_others(K, win, r, tv.T_b_a, X, idx)
        if T is None:  # the two-view points do not explain another view: a wrong pair, try a nearer one
            continue
        mask = np.zeros(len(win.uv0), bool)
        mask[idx] = True
        return T, 1.0 / X[:, 2], mask
    return _rotation_init(K, win)


def _pnp_others(
    K: np.ndarray, win: TrackWindow, r: int, T_r_0: np.ndarray, X: np.ndarray, idx: np.ndarray
) -> np.ndarray | None:  # T_i_0 [W, 4, 4]
    """Every view but 0 and ``r`` posed by PnP on the points triangulated from views 0 and ``r``."""
    n = len(win.obs)
    T = np.tile(np.eye(4), (n, 1, 1))
    T[r] = T_r_0
    for i in range(1, n):
        if i == r:
            continue
        seen = np.isfinite(win.obs[i, idx]).all(1)
        res = pnp(X[seen], win.obs[i, idx[seen]], K, 2.0 * THRESHOLD_PX, MIN_TRACKS)
        if res.T_tgt_src is None:
            return None
        T[i] = res.T_tgt_src
    return T


def _rotation_init(K: np.ndarray, win: TrackWindow):  # -> (T_i_0 [W, 4, 4], rho [N], mask [N]) or None
    """No two-view geometry (a pan, little parallax): rotations from homographies, no translation, the
    tracks far away (inverse depth 0.1); the BA finds what translation there is."""
    n = len(win.obs)
    mask = np.isfinite(win.obs[1:]).all(-1).sum(0) >= 2
    if mask.sum() < MIN_TRACKS:
        return None
    T = np.tile(np.eye(4), (n, 1, 1))
    for i in range(1, n):
        ok = mask & np.isfinite(win.obs[i]).all(1)
        R = rotation_from_homography(K, win.uv0[ok], win.obs[i, ok])
        if R is None:
            return None
        T[i, :3, :3] = R
    return T, np.full(int(mask.sum()), 0.1), mask


def window_profile(
    intr: CameraIntrinsics, win: TrackWindow, scales: np.ndarray, starts: tuple[float, ...] = DEFAULT_STARTS
) -> np.ndarray | None:  # [S] Cauchy cost per scale, None when the window has no two-view geometry
    """The window's BA cost at each focal scale (module doc, step 3): for each start scale, the poses
    initialised at that focal and the BA swept outwards from it, warm-started; the lowest cost per scale
    over the starts (a profile is a minimum over poses: a start far from the truth may stay in another
    basin, docs/results.md session 13)."""
    scales = np.asarray(scales, np.float64)
    costs = np.full(len(scales), np.inf)
    for s0 in starts:
        j0 = int(np.argmin(np.abs(scales - s0)))
        init = _init_poses(intr.with_focal(float(scales[j0])).K, win)
        if init is None:
            if s0 == starts[0]:
                return None
            continue
        T0, rho0, mask = init
        uv0, obs = win.uv0[mask], win.obs[:, mask]
        for order in (range(j0, len(scales)), range(j0, -1, -1)):  # outwards from the start, warm-started
            T, rho = T0, rho0
            for j in order:
                K = intr.with_focal(float(scales[j])).K
                T, rho = bundle_adjust(K, T, uv0, rho, obs, THRESHOLD_PX)
                costs[j] = min(costs[j], track_cost(K, T, win.uv0, win.obs, THRESHOLD_PX))
    return costs


def estimate_mono_focal(
    frames: list[Frame],  # the first frames of the sequence (colour only is read)
    flow: FlowEstimator,
    max_side: int = 320,  # point-map resolution
    gap: int = 3,  # frames between the views of a window
    window: int = 6,  # views per window
    stride: int = 6,  # frames between the windows' first frames
    max_points: int = 1500,
    scales: np.ndarray | None = None,
    min_windows: int = 3,
    min_gain: float = 0.05,
    agree: float = 0.04,
    seed: int = 0,
    starts: tuple[float, ...] = DEFAULT_STARTS,
) -> MonoFocalEstimate:
    """The focal scale (estimated / given) from the flow of ``frames`` (module doc)."""
    xs = DEFAULT_SCALES if scales is None else np.asarray(scales, np.float64)
    intr = pointmap_intrinsics(frames[0].intrinsics, max_side)
    rng = np.random.default_rng(seed)
    imgs = [resize_image(f.image, intr) for f in frames]
    span = gap * (window - 1)
    profiles, tracks = [], 0
    for start in range(0, len(frames) - span, stride):
        win = window_tracks(imgs[start : start + span + 1 : gap], flow, max_points, rng)
        p = window_profile(intr, win, xs, starts)
        if p is None or not np.isfinite(p).all():
            continue
        profiles.append(p)
        tracks += len(win.uv0)
    if not profiles:
        return MonoFocalEstimate(1.0, 0, 0, float("nan"), float("nan"), (), 0, False)
    P = np.stack(profiles)  # [windows, S]
    total = P.sum(0)
    s_best, _, inside = parabola_min(xs, total)
    per = tuple(float(parabola_min(xs, p)[0]) for p in P)
    agreeing = int(sum(abs(s - s_best) <= agree for s in per))
    c1 = float(np.interp(1.0, xs, total))
    est = MonoFocalEstimate(s_best, len(P), tracks, c1, float(total.min()), per, agreeing, False)
    ok = inside and est.windows >= min_windows and est.gain >= min_gain and 2 * agreeing > est.windows
    log.info(
        "mono focal: scale %.3f from %d windows (%d agree), cost %.0f -> %.0f%s",
        s_best, est.windows, agreeing, c1, est.cost_best, "" if ok else " (not trusted)",
    )  # fmt: skip
    return replace(est, ok=ok)


def mono_focal_correction(
    frames: list[Frame], flow: FlowEstimator, cfg: EncoderConfig
) -> tuple[float, MonoFocalEstimate]:  # -> (focal scale to apply, 1.0: none; the estimate)
    """The estimate on ``frames`` and whether to apply it: ``ok`` (with ``encoder.mono_focal_min_gain``)
    and more than ``encoder.mono_focal_min_dev`` from 1; else the given intrinsics stay, unchanged."""
    est = estimate_mono_focal(frames, flow, max_side=cfg.pointmap_max_side, min_gain=cfg.mono_focal_min_gain)
    apply = est.ok and abs(est.scale - 1.0) > cfg.mono_focal_min_dev
    if apply:
        log.info(
            "mono focal: given fx %.1f -> %.1f", frames[0].intrinsics.fx, frames[0].intrinsics.fx * est.scale
        )
    return (est.scale if apply else 1.0), est


def rescale_focal(frame: Frame, scale: float) -> Frame:
    """``frame`` with both focal lengths times ``scale`` (the same frame at 1.0)."""
    if scale == 1.0:
        return frame
    return replace(frame, intrinsics=frame.intrinsics.with_focal(scale))
