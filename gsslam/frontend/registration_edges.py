"""The depth camera's turn against the colour camera, from depth edges against colour edges.

A Kinect v1's depth camera is turned ~0.5 deg per axis against its colour camera (LIRIS: rotation vector
(0.468, -0.452, -0.155) deg), which moves every re-projected depth pixel by ``f * angle`` (~4.7 px at 585
px) whatever its depth; the baseline moves it by ``f * b / z``. Both are seen in a single frame without
motion: the depth image's occluding contours, re-projected into the colour camera, must land on the colour
image's edges (docs/results.md, "The depth camera's turn from edges, session 17").

Depth edges: jumps between horizontal (or vertical) neighbours of the depth image larger than
``max(min_jump_m, min_jump_rel * z)``, taken at the midpoint between the two pixels with the near side's
depth (the occluding surface's contour). Colour edges: the grey image's gradient, blurred, split by
orientation: a horizontal jump's contour runs vertically and is scored by ``|d/du|`` of the colour image, a
vertical jump's by ``|d/dv|``; each gradient ``g`` is saturated as ``g / (g + p)``, ``p`` its 90th
percentile, so that a few strong texture edges do not dominate while every edge keeps its peak. The score is
the mean saturated gradient at the re-projected contour points (asymmetric: each depth edge needs a colour
edge, a colour texture edge with no depth edge costs nothing). The turn is the score's maximum: a scan of
``(rx, ry)`` (they move edges along u and v), then a Nelder-Mead refinement of ``(rx, ry, rz)``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import minimize

from gsslam.geometry import so3_exp
from gsslam.types import CameraIntrinsics, Frame

__all__ = ["EdgeTurn", "colour_edge_maps", "depth_edges", "edge_score", "estimate_turn"]

log = logging.getLogger(__name__)

SCAN_HALF_DEG = 1.5  # (rx, ry) scanned within +-this
SCAN_STEP_DEG = 0.1
MAX_GAP = 6  # invalid depth pixels between the two sides of a contour (a Kinect's shadow)
MIN_POINTS = 200  # contour points of each orientation (all frames) for the turn to count as observed


@dataclass(frozen=True)
class EdgeTurn:
    """The turn the edges give (R_colour_depth's rotation vector, degrees) and its evidence."""

    rotation_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    observed: bool = False  # enough contour points of both orientations, the maximum inside the scan
    frames: int = 0
    points_u: int = 0  # contour points of horizontal jumps (they fix rotations about y)
    points_v: int = 0  # ... of vertical jumps (about x)
    score: float = float("nan")  # mean saturated colour gradient at the contour, at the estimate
    score_unturned: float = float("nan")  # ... at no turn
    baseline_m: float = float("nan")  # the baseline the edges fit with the turn (a check of the estimate's)
    frame_rotations_deg: tuple[tuple[float, float], ...] = ()  # each frame's own (rx, ry) scan maximum
    shift_px: float = 0.0  # the contours' move towards their far side (fitted with the turn; fattening)
    rotation_deg_with_baseline: tuple[float, float, float] = (0.0, 0.0, 0.0)  # fitted with baseline_m


@dataclass(frozen=True)
class _Edges:  # one frame's contour points in the depth camera and its colour edge maps
    X: np.ndarray  # [N, 3] contour points in the depth camera frame (metres)
    dX: np.ndarray  # [N, 3] their move per pixel of the contour towards the far side
    along_u: np.ndarray  # [N] bool: a horizontal jump (scored by the colour gradient along u)
    grad_u: np.ndarray  # [H, W] saturated |d/du| of the colour image
    grad_v: np.ndarray  # [H, W] saturated |d/dv|


def depth_edges(
    depth: np.ndarray,  # [H, W] metres, NaN invalid
    min_jump_m: float = 0.05,
    min_jump_rel: float = 0.04,
    max_gap: int = MAX_GAP,
) -> tuple[np.ndarray, ...]:  # u [N], v [N], z [N], along_u [N] bool, far_sign [N] (+1: far side at +u / +v)
    """Occluding contours: where the depths of two valid pixels of a row (column) jump, with at most
    ``max_gap`` invalid pixels between them (a Kinect's shadow beside an occluding edge, mixed pixels), the
    middle between them with the near depth."""
    out = []
    for axis in (1, 0):
        d = depth if axis == 1 else depth.T
        valid = np.isfinite(d) & (d > 0)
        inval = np.concatenate([np.zeros((d.shape[0], 1), int), np.cumsum(~valid, axis=1)], axis=1)
        for g in range(min(max_gap, d.shape[1] - 2) + 1):
            a, b = d[:, : d.shape[1] - g - 1], d[:, g + 1 :]
            ok = valid[:, : d.shape[1] - g - 1] & valid[:, g + 1 :]
            ok &= (inval[:, g + 1 : d.shape[1]] - inval[:, 1 : d.shape[1] - g]) == g  # all between invalid
            near = np.where(ok, np.fmin(a, b), np.inf)
            jump = ok & (np.abs(np.where(ok, a - b, 0.0)) > np.maximum(min_jump_m, min_jump_rel * near))
            rows, cols = np.nonzero(jump)
            a_near = a[rows, cols] <= b[rows, cols]
            pos = cols + 0.5 * (g + 1)  # the middle of the gap
            z = np.where(a_near, a[rows, cols], b[rows, cols]).astype(np.float64)
            u, v = (pos, rows.astype(np.float64)) if axis == 1 else (rows.astype(np.float64), pos)
            out.append((u, v, z, np.full(len(z), axis == 1), np.where(a_near, 1.0, -1.0)))
    return tuple(np.concatenate([o[i] for o in out]) for i in range(5))  # type: ignore[return-value]


def colour_edge_maps(
    image: np.ndarray,  # [H, W, 3] float in [0, 1]
    blur_sigma: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:  # [H, W] float32 each: saturated |d/du|, |d/dv|
    """The colour image's gradient along u and v, each saturated as ``g / (g + p)`` (``p``: its 90th
    percentile)."""
    grey = cv2.cvtColor(np.ascontiguousarray(image, dtype=np.float32), cv2.COLOR_RGB2GRAY)
    grey = cv2.GaussianBlur(grey, (0, 0), blur_sigma)
    maps = []
    for dx, dy in ((1, 0), (0, 1)):
        g = np.abs(cv2.Sobel(grey, cv2.CV_32F, dx, dy, ksize=3))
        moving = g > 1e-4  # pixels where the image changes at all
        p = float(np.percentile(g[moving], 90)) if moving.any() else 0.0
        maps.append(g / (g + p) if p > 0 else np.zeros_like(g))
    return maps[0], maps[1]


def _bilinear(img: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:  # [N], 0 outside
    h, w = img.shape
    inside = (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
    uc, vc = np.clip(u, 0, w - 1.001), np.clip(v, 0, h - 1.001)
    u0, v0 = uc.astype(np.int64), vc.astype(np.int64)
    fu, fv = uc - u0, vc - v0
    val = (img[v0, u0] * (1 - fu) * (1 - fv) + img[v0, u0 + 1] * fu * (1 - fv)
           + img[v0 + 1, u0] * (1 - fu) * fv + img[v0 + 1, u0 + 1] * fu * fv)  # fmt: skip
    return np.where(inside, val, 0.0)


def edge_score(
    edges: list[_Edges],
    rotation_deg: np.ndarray,  # [3] R_colour_depth's rotation vector
    baseline_m: float,
    colour: CameraIntrinsics,
    shift_px: float = 0.0,  # every contour moved this far towards its far side (the sensor's fattening)
) -> float:
    """The mean saturated colour gradient at the contour points re-projected with this turn and baseline."""
    R = so3_exp(np.radians(np.asarray(rotation_deg, dtype=np.float64)))
    total, n = 0.0, 0
    for e in edges:
        Xc = (e.X + shift_px * e.dX) @ R.T
        Xc[:, 0] += baseline_m
        z = np.maximum(Xc[:, 2], 1e-6)
        u = colour.cx + colour.fx * Xc[:, 0] / z
        v = colour.cy + colour.fy * Xc[:, 1] / z
        total += _bilinear(e.grad_u, u[e.along_u], v[e.along_u]).sum()
        total += _bilinear(e.grad_v, u[~e.along_u], v[~e.along_u]).sum()
        n += len(u)
    return total / max(n, 1)


def _frame_edges(frame: Frame, depth_intr: CameraIntrinsics, blur_sigma: float) -> _Edges | None:
    if frame.depth is None:
        return None
    u, v, z, along_u, far = depth_edges(frame.depth)
    if len(z) == 0:
        return None
    X = np.stack([(u - depth_intr.cx) / depth_intr.fx * z, (v - depth_intr.cy) / depth_intr.fy * z, z], 1)
    dX = np.zeros_like(X)
    dX[:, 0] = np.where(along_u, far * z / depth_intr.fx, 0.0)
    dX[:, 1] = np.where(along_u, 0.0, far * z / depth_intr.fy)
    gu, gv = colour_edge_maps(frame.image, blur_sigma)
    return _Edges(X, dX, along_u, gu, gv)


def _scan(edges: list[_Edges], baseline_m: float, colour: CameraIntrinsics) -> tuple[np.ndarray, bool]:
    grid = np.arange(-SCAN_HALF_DEG, SCAN_HALF_DEG + 1e-9, SCAN_STEP_DEG)
    s = np.array(
        [[edge_score(edges, np.array([rx, ry, 0.0]), baseline_m, colour) for ry in grid] for rx in grid]
    )
    i, j = np.unravel_index(int(np.argmax(s)), s.shape)
    inside = 0 < i < len(grid) - 1 and 0 < j < len(grid) - 1
    return np.array([grid[i], grid[j], 0.0]), bool(inside)


def _maximise(score, p0: np.ndarray, step: np.ndarray) -> np.ndarray:  # Nelder-Mead from p0, first steps
    res = minimize(lambda p: -score(p), p0, method="Nelder-Mead",
                   options={"initial_simplex": p0 + np.vstack([np.zeros(len(p0)), np.diag(step)]),
                            "xatol": 0.002, "fatol": 1e-6, "maxiter": 400})  # fmt: skip
    return res.x if -res.fun >= score(p0) else p0


def estimate_turn(
    frames: list[Frame],  # as the dataset hands them out (depth in the depth camera's grid)
    depth_intr: CameraIntrinsics,  # the registration's depth camera
    colour_intr: CameraIntrinsics,  # ... and colour camera
    baseline_m: float,  # the registration's baseline (held)
    max_frames: int = 10,  # frames used, spread over ``frames``
    blur_sigma: float = 1.0,
    fit_shift: bool = True,  # fit the contours' move towards the far side too (a real sensor's fattening)
) -> EdgeTurn:
    """R_colour_depth's rotation vector that best puts the depth contours on colour edges (module doc)."""
    pick = np.unique(np.linspace(0, len(frames) - 1, min(max_frames, len(frames))).round().astype(int))
    edges = [e for e in (_frame_edges(frames[i], depth_intr, blur_sigma) for i in pick) if e is not None]
    n_u = sum(int(e.along_u.sum()) for e in edges)
    n_v = sum(int((~e.along_u).sum()) for e in edges)
    if n_u < MIN_POINTS or n_v < MIN_POINTS:
        log.info("depth camera's turn from edges: not observed (%d + %d contour points)", n_u, n_v)
        return EdgeTurn(frames=len(edges), points_u=n_u, points_v=n_v)
    r0, inside = _scan(edges, baseline_m, colour_intr)
    n = 4 if fit_shift else 3

    def score(p: np.ndarray, b: float = baseline_m) -> float:
        return edge_score(edges, p[:3], b, colour_intr, float(p[3]) if len(p) > 3 else 0.0)

    p = _maximise(score, np.r_[r0, np.zeros(n - 3)], np.full(n, 0.1))
    pb = _maximise(
        lambda q: score(q[:-1], float(q[-1])), np.r_[p, baseline_m], np.r_[np.full(n, 0.1), 0.005]
    )  # the edges' b
    per_frame = tuple(
        tuple(round(float(x), 2) for x in _scan([e], baseline_m, colour_intr)[0][:2]) for e in edges
    )
    turn = EdgeTurn(
        tuple(round(float(x), 4) for x in p[:3]), inside, len(edges), n_u, n_v, score(p),
        score(np.zeros(n)), float(pb[-1]), per_frame, float(p[3]) if fit_shift else 0.0,
        tuple(round(float(x), 4) for x in pb[:3]),
    )  # fmt: skip
    log.info("depth camera's turn from edges: (%.3f, %.3f, %.3f) deg, %s (%d frames, %d + %d contour points, "
             "score %.4f at no turn -> %.4f; contours moved %.2f px towards the far side; the edges' "
             "baseline %.1f mm); each frame's (rx, ry): %s", *turn.rotation_deg,
             "observed" if inside else "not observed (maximum on the scan's border)", turn.frames, n_u, n_v,
             turn.score_unturned, turn.score, turn.shift_px, 1000 * turn.baseline_m, per_frame)  # fmt: skip
    return turn
