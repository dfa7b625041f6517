"""Colour focal length from depth: recover the colour camera of an unregistered RGB-D sensor.

Kinect v1 datasets such as 7-Scenes ship the depth image in the depth camera's pixel grid and one set
of intrinsics (the depth camera's, fx = fy = 585) for both images, while the colour camera has a
shorter focal length (~525 px). PnP on colour flow with the depth focal length makes every rotation
and lateral motion ~10 % too small: the whole trajectory shrinks (docs/results.md, "Accuracy at
length").

The depth images alone give metric motion (point-to-plane ICP, ``frontend/icp.py``), independent of
the colour camera. For a frame pair with ICP motion ``T_b_a`` and colour flow ``u_a -> u_b``, a
candidate focal ratio ``k = f_depth / f_colour`` predicts where each colour pixel goes::

    z   = depth_a[c + k (u_a - c)]               (the depth camera sees the point at that pixel)
    X   = z [(u_a - c) k / f_depth, 1]           (back-projected with f_colour = f_depth / k)
    u_b' = c + (f_depth / k) [X'_x, X'_y] / X'_z,  X' = T_b_a X

:func:`estimate_focal_ratio` scans ``k`` and keeps the one with the smallest truncated reprojection
error over a few pairs at the start of the sequence, taking the given intrinsics as the depth
camera's and the two cameras as concentric. :func:`reprojection_cost` is the general form: any colour
and depth focal lengths and a baseline ``b`` (the depth camera's centre at ``x = b`` in the colour
camera frame: the colour pixel's depth is read at ``c + f_depth (x_n - [b / z, 0])`` and the motion
acts in the depth camera, ``X'_colour = T_b_a (X - b) + b``). :mod:`gsslam.frontend.depth_registration`
fits it (ratio, baseline, and whose intrinsics were given) and registers the frames.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np

from gsslam.frontend.encoder import depth_edge_mask
from gsslam.frontend.flow import FlowEstimator, forward_backward_mask, textured_mask
from gsslam.frontend.icp import TRACK_STRIDES, icp_point_to_plane
from gsslam.geometry import so3_log
from gsslam.types import CameraIntrinsics, Frame

log = logging.getLogger(__name__)

GRID_STRIDE_PX = 6  # colour pixels sampled every this many pixels
TRUNCATE_PX = 4.0  # reprojection errors beyond this count as this (flow outliers, occlusions)
ICP_STRIDES = TRACK_STRIDES + (4,)  # full resolution down to 160x120 points


@dataclass(frozen=True)
class FocalEstimate:
    ratio: float  # k = f_depth / f_colour (1: the given intrinsics already fit the colour image)
    pairs: int  # frame pairs used
    points: int  # colour pixels used over all pairs
    cost_at_one: float  # mean truncated reprojection error (px) at k = 1
    cost_at_best: float  # at k = ratio
    ok: bool  # enough pairs and points, and the minimum inside the scanned range


@dataclass(frozen=True)
class FlowPair:
    """One frame pair for the registration estimates: colour flow, the depth images and their ICP motion."""

    uv_a: np.ndarray  # [M, 2] colour pixels in frame a
    uv_b: np.ndarray  # [M, 2] their flow targets in frame b
    depth_a: np.ndarray  # [H, W] metres (depth camera grid), NaN invalid and at depth edges
    raw_a: np.ndarray  # [H, W] float32 metres, frame a's depth as given (for ICP at other intrinsics)
    raw_b: np.ndarray  # [H, W] float32 metres, frame b's
    T_b_a: np.ndarray  # [4, 4] ICP motion (depth camera) at the given intrinsics
    index_a: int = -1  # frame a's position in the frames the pairs came from (-1: not known)
    index_b: int = -1  # frame b's


def pair_icp(
    pair: FlowPair, intr: CameraIntrinsics, strides: tuple[int, ...] = ICP_STRIDES
) -> np.ndarray | None:
    """``T_b_a`` of the pair's depth images back-projected with ``intr`` (None when ICP refuses)."""
    icp = icp_point_to_plane(pair.raw_a, pair.raw_b, intr, np.eye(4), strides=strides)
    return icp.T_tgt_src if icp.ok else None


def _pair(
    fa: Frame, fb: Frame, flow: FlowEstimator, rng: np.random.Generator, max_points: int, refused_ok: bool
) -> FlowPair | None:
    intr = fa.intrinsics
    icp = icp_point_to_plane(fa.depth, fb.depth, intr, np.eye(4), strides=ICP_STRIDES)
    if not icp.ok and not refused_ok:
        return None
    fw = flow(fa.image, fb.image)
    bw = flow(fb.image, fa.image)
    valid = forward_backward_mask(fw, bw, 1.0) & textured_mask(fa.image)
    grid = np.zeros_like(valid)
    grid[GRID_STRIDE_PX // 2 :: GRID_STRIDE_PX, GRID_STRIDE_PX // 2 :: GRID_STRIDE_PX] = True
    vs, us = np.nonzero(valid & grid)
    if len(us) > max_points:
        keep = rng.choice(len(us), max_points, replace=False)
        vs, us = vs[keep], us[keep]
    uv_a = np.stack([us, vs], 1).astype(np.float64)
    uv_b = uv_a + fw[vs, us].astype(np.float64)
    depth = np.where(depth_edge_mask(fa.depth), np.nan, fa.depth).astype(np.float64)
    raw_a, raw_b = (np.asarray(d, dtype=np.float32) for d in (fa.depth, fb.depth))
    return FlowPair(uv_a, uv_b, depth, raw_a, raw_b, icp.T_tgt_src)


def flow_pairs(
    frames: list[Frame],
    flow: FlowEstimator,
    gap: int = 4,
    max_pairs: int = 12,
    min_rotation_deg: float = 1.0,
    max_points: int = 3000,
    seed: int = 0,
    fallback_gap: int | None = None,
    icp_refused_ok: bool = False,
) -> list[FlowPair]:
    """Pairs ``(i, i + gap)`` (i every ``gap // 2``) whose ICP motion turns >= ``min_rotation_deg``.

    ``fallback_gap``: when ``gap`` gives fewer than ``max_pairs`` pairs (a quick hand: ICP from identity
    refuses the wider pairs), pairs ``(i, i + fallback_gap)`` fill the list up to ``max_pairs``. Where
    ``gap`` fills it the result is the same as without (docs/results.md, "Depth not registered to colour,
    session 9"). ``icp_refused_ok``: a pair whose ICP refuses (e.g. ill-conditioned on a bare wall) is kept
    with ``T_b_a`` the identity (for callers that solve the motion themselves, as the delay estimate does).
    """
    rng = np.random.default_rng(seed)
    pairs: list[FlowPair] = []
    for g in (gap,) if fallback_gap is None or fallback_gap == gap else (gap, fallback_gap):
        for i in range(0, len(frames) - g, max(1, g // 2)):
            if len(pairs) >= max_pairs:
                break
            fa, fb = frames[i], frames[i + g]
            if fa.depth is None or fb.depth is None:
                continue
            p = _pair(fa, fb, flow, rng, max_points, icp_refused_ok)
            if p is None or np.degrees(np.linalg.norm(so3_log(p.T_b_a[:3, :3]))) < min_rotation_deg:
                continue
            pairs.append(replace(p, index_a=i, index_b=i + g))
        if g != gap:
            log.info("registration pairs: %d with the fallback gap %d", len(pairs), g)
    return pairs


def depth_camera_points(
    pair: FlowPair,
    colour: CameraIntrinsics,  # of the colour image
    f_depth: tuple[float, float],  # (fx, fy) of the depth camera (same principal point)
    baseline_m: float = 0.0,  # the depth camera's centre in the colour camera frame, along x
) -> tuple[np.ndarray, np.ndarray]:  # X [M, 3] depth camera frame (metres), ok [M] bool (depth found)
    """The scene point behind each flow pixel ``pair.uv_a``, in the depth camera's frame.

    With a baseline the depth pixel of a colour pixel depends on its depth: found by two fixed-point
    steps from the zero-baseline pixel."""
    c = np.array([colour.cx, colour.cy])
    fc = np.array([colour.fx, colour.fy])
    fd = np.asarray(f_depth, dtype=np.float64)
    h, w = pair.depth_a.shape
    xn = (pair.uv_a - c) / fc  # [M, 2] normalised colour rays
    z = np.full(len(xn), np.inf)  # first step: the zero-baseline pixel
    for _ in range(3 if baseline_m else 1):
        pd = np.rint(c + fd * (xn - np.array([baseline_m, 0.0]) / z[:, None])).astype(int)
        inside = (pd[:, 0] >= 0) & (pd[:, 0] < w) & (pd[:, 1] >= 0) & (pd[:, 1] < h)
        zz = np.full(len(pd), np.nan)
        zz[inside] = pair.depth_a[pd[inside, 1], pd[inside, 0]]
        z = np.where(np.isfinite(zz) & (zz > 0), zz, z)
    ok = np.isfinite(zz) & (zz > 0)
    X = np.concatenate([xn * zz[:, None], zz[:, None]], 1) - np.array([baseline_m, 0.0, 0.0])
    return X, ok


def reprojection_cost(
    pair: FlowPair,
    T_b_a: np.ndarray,  # [4, 4] depth-camera motion
    colour: CameraIntrinsics,  # of the colour image
    f_depth: tuple[float, float],  # (fx, fy) of the depth camera (same principal point)
    baseline_m: float = 0.0,  # the depth camera's centre in the colour camera frame, along x
) -> tuple[float, int]:  # -> (sum of truncated errors in px, count)
    """Move each flow pixel by ``T_b_a`` through its depth; compare with the flow target (module doc)."""
    X, ok = depth_camera_points(pair, colour, f_depth, baseline_m)
    b = np.array([baseline_m, 0.0, 0.0])
    Xb = X[ok] @ T_b_a[:3, :3].T + T_b_a[:3, 3] + b  # colour camera frame b
    front = Xb[:, 2] > 1e-3
    c = np.array([colour.cx, colour.cy])
    uv = c + np.array([colour.fx, colour.fy]) * Xb[front, :2] / Xb[front, 2:3]
    err = np.linalg.norm(uv - pair.uv_b[ok][front], axis=1)
    return float(np.minimum(err, TRUNCATE_PX).sum()), int(front.sum())


def mean_cost(
    pairs: list[FlowPair],
    Ts: list[np.ndarray],
    colour: CameraIntrinsics,
    f_depth: tuple[float, float],
    baseline_m: float = 0.0,
) -> tuple[float, int]:  # -> (mean truncated error px over all pairs, points)
    tot, cnt = 0.0, 0
    for p, T in zip(pairs, Ts):
        s, m = reprojection_cost(p, T, colour, f_depth, baseline_m)
        tot, cnt = tot + s, cnt + m
    return tot / max(cnt, 1), cnt


def _cost(
    pair: FlowPair, k: float, intr: CameraIntrinsics
) -> tuple[float, int]:  # given = depth, no baseline
    colour = replace(intr, fx=intr.fx / k, fy=intr.fy / k)
    return reprojection_cost(pair, pair.T_b_a, colour, (intr.fx, intr.fy))


def parabola_min(xs: np.ndarray, cs: np.ndarray) -> tuple[float, float, bool]:
    """Minimum of a scan ``cs`` over the even grid ``xs``, refined by the parabola through it and its
    neighbours: (x, cost at the grid minimum, whether the minimum is inside the grid)."""
    j = int(np.argmin(cs))
    x = float(xs[j])
    inside = 0 < j < len(xs) - 1
    if inside:
        a, b, c = cs[j - 1], cs[j], cs[j + 1]
        den = a - 2 * b + c
        if den > 0:
            x += 0.5 * (a - c) / den * float(xs[j + 1] - xs[j])
    return x, float(cs[j]), inside


def estimate_focal_ratio(
    frames: list[Frame],  # the first frames of the sequence, with depth
    flow: FlowEstimator,
    gap: int = 4,
    max_pairs: int = 12,
    min_rotation_deg: float = 1.0,
    ratios: np.ndarray | None = None,
    max_points: int = 3000,
    seed: int = 0,
) -> FocalEstimate:
    """Scan ``k = f_depth / f_colour`` over ``ratios`` (default 0.80-1.25, step 0.0025); see the module doc.

    Pairs ``(i, i + gap)`` whose ICP motion turns at least ``min_rotation_deg`` (rotation is what makes
    the focal length observable) are used, up to ``max_pairs``.
    """
    ks = np.arange(0.80, 1.2501, 0.0025) if ratios is None else np.asarray(ratios, dtype=np.float64)
    pairs = flow_pairs(frames, flow, gap, max_pairs, min_rotation_deg, max_points, seed)
    intr = frames[0].intrinsics
    if not pairs:
        return FocalEstimate(1.0, 0, 0, float("nan"), float("nan"), False)
    costs = np.zeros(len(ks))
    n = 0
    for j, k in enumerate(ks):
        tot, cnt = 0.0, 0
        for p in pairs:
            s, m = _cost(p, k, intr)
            tot, cnt = tot + s, cnt + m
        costs[j] = tot / max(cnt, 1)
        n = max(n, cnt)
    k_best, cost_best, inside = parabola_min(ks, costs)
    c1 = float(np.interp(1.0, ks, costs))
    ok = inside and len(pairs) >= 3 and n >= 300
    return FocalEstimate(k_best, len(pairs), n, c1, cost_best, ok)
