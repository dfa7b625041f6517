"""Verification: ORB matches between the loop frames, lifted to 3D, RANSAC on 3D-3D.

For the most co-visible view pairs (a of submap i, b of submap m), ORB descriptors are matched
(brute-force Hamming, mutual best match) and both keypoints are lifted by their submaps' point
maps to local 3D points ``X_i`` and ``X_m``. RANSAC over minimal 3-point samples fits
``X_i ~ T_i_m X_m`` with Umeyama (Sim(3) for mono, SE(3) for RGB-D); the inliers of the best
model, refitted, become the loop constraint.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import cv2
import numpy as np

from gsslam.config import LoopConfig
from gsslam.geometry import transform_points, umeyama
from gsslam.loop.ray_gate import range_inlier_test, ray_inlier_test
from gsslam.loop.types import LoopCandidate, LoopConstraint, SubmapRecord, Verdict

log = logging.getLogger(__name__)

_MATCHER = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True)


def match_3d(
    rec_i: SubmapRecord, rec_m: SubmapRecord, view_pairs: tuple[tuple[int, int], ...]
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Matched 3D point pairs over the given view pairs: (X_i [N, 3], X_m [N, 3]) in local frames,
    and the views of submaps i and m each match was seen in (``view_i``, ``view_m`` [N])."""
    Xi, Xm, views, views_m = [], [], [], []
    for a, b in view_pairs:
        fa, fb = rec_i.features[a], rec_m.features[b]
        if len(fa.descriptors) < 3 or len(fb.descriptors) < 3:
            continue
        matches = _MATCHER.match(fa.descriptors, fb.descriptors)
        if not matches:
            continue
        qi = np.array([mt.queryIdx for mt in matches])
        ti = np.array([mt.trainIdx for mt in matches])
        Xi.append(fa.points_local[qi])
        Xm.append(fb.points_local[ti])
        views.append(np.full(len(qi), a, dtype=np.int64))
        views_m.append(np.full(len(qi), b, dtype=np.int64))
    if not Xi:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    return np.concatenate(Xi), np.concatenate(Xm), np.concatenate(views), np.concatenate(views_m)


def _iterations_for(inlier_fraction: float, confidence: float = 0.999) -> int:
    """Samples needed to draw one all-inlier triple with the given confidence (adaptive stop)."""
    w3 = inlier_fraction**3
    if w3 >= 1.0 - 1e-12:
        return 1
    return int(np.ceil(np.log(1.0 - confidence) / np.log(1.0 - w3))) + 1


def ransac_transform(
    X_i: np.ndarray,  # [N, 3]
    X_m: np.ndarray,  # [N, 3]
    threshold: float,
    with_scale: bool,
    iterations: int,
    rng: np.random.Generator,
    inlier_test: Callable[[np.ndarray], np.ndarray] | None = None,
) -> tuple[np.ndarray | None, np.ndarray]:
    """Best ``T_i_m`` (4x4) and its inlier mask [N]; ``(None, all-False)`` when no model fits.

    A pair is an inlier when ``|T X_m - X_i| < threshold``, or, given ``inlier_test`` (``T`` -> [N]
    bool), when that says so (``threshold`` is then unused).
    """
    if inlier_test is None:

        def inlier_test(T: np.ndarray) -> np.ndarray:
            return np.linalg.norm(transform_points(T, X_m) - X_i, axis=1) < threshold

    n = len(X_i)
    best = np.zeros(n, dtype=bool)
    if n < 3:
        return None, best
    samples = np.stack([rng.choice(n, size=3, replace=False) for _ in range(iterations)])
    needed = iterations
    for it, idx in enumerate(samples):
        if it >= needed:
            break
        A, B = X_m[idx], X_i[idx]
        # skip degenerate (near-collinear) samples
        if np.linalg.norm(np.cross(A[1] - A[0], A[2] - A[0])) < 1e-9:
            continue
        try:
            T = umeyama(A, B, with_scale=with_scale)
        except (ValueError, np.linalg.LinAlgError):
            continue
        inl = inlier_test(T)
        if inl.sum() > best.sum():
            best = inl
            needed = min(iterations, _iterations_for(best.mean()))
    if best.sum() < 3:
        return None, best
    for _ in range(2):  # refit on inliers, re-select
        T = umeyama(X_m[best], X_i[best], with_scale=with_scale)
        inl = inlier_test(T)
        if inl.sum() < 3:
            break
        best = inl
    T = umeyama(X_m[best], X_i[best], with_scale=with_scale)
    return T, best


def inlier_threshold(rec_i: SubmapRecord, cfg: LoopConfig, mode: str) -> float:
    """Inlier distance in submap-i local units: metres for RGB-D, relative to depth for mono."""
    if mode == "rgbd":
        return cfg.inlier_threshold_m
    return cfg.inlier_threshold_rel * rec_i.median_depth


def verify_candidate(
    cand: LoopCandidate,
    rec_i: SubmapRecord,
    rec_m: SubmapRecord,
    cfg: LoopConfig,
    mode: str,
    rng: np.random.Generator,
) -> Verdict:
    """RANSAC-verify one candidate; the :class:`Verdict` says why a rejected one failed."""
    X_i, X_m, view_i, view_m = match_3d(rec_i, rec_m, cand.view_pairs[: cfg.verify_view_pairs])
    thr = inlier_threshold(rec_i, cfg, mode)
    test = None
    if mode == "mono" and cfg.mono_inlier_gate == "ray" and len(X_i):
        test = ray_inlier_test(X_i, X_m, view_i, rec_i.T_local_cam, cfg.ray_threshold_deg, cfg.ray_depth_rel)
    elif mode == "mono" and cfg.mono_inlier_gate == "range" and len(X_i):
        test = range_inlier_test(X_i, X_m, view_i, rec_i.T_local_cam, cfg.inlier_threshold_rel)
    T, inl = ransac_transform(
        X_i,
        X_m,
        thr,
        with_scale=(mode == "mono"),
        iterations=cfg.ransac_iterations,
        rng=rng,
        inlier_test=test,
    )
    n_inl = int(inl.sum())
    ratio = n_inl / max(1, len(X_i))
    log.debug("loop %d-%d: %d matches, %d inliers (%.2f)", cand.i, cand.m, len(X_i), n_inl, ratio)
    if len(X_i) < cfg.min_inliers:
        return Verdict(None, len(X_i), n_inl, "too few matches")
    if T is None or n_inl < cfg.min_inliers:
        return Verdict(None, len(X_i), n_inl, "too few inliers")
    if ratio < cfg.min_inlier_ratio:
        return Verdict(None, len(X_i), n_inl, "low inlier ratio")
    loop = LoopConstraint(
        i=cand.i,
        m=cand.m,
        X_i=X_i[inl],
        X_m=X_m[inl],
        T_i_m=T,
        inlier_ratio=ratio,
        score=cand.score,
        threshold=thr,
        view_i=view_i[inl],
        view_m=view_m[inl],
    )
    return Verdict(loop, len(X_i), n_inl, "verified")
