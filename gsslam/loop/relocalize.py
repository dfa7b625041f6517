"""Re-localization across chains: place a new chain's submap against an earlier chain's submaps.

After tracking loss the new chain has its own graph and no pose prior relative to the earlier map,
so the overlap test of :mod:`gsslam.loop.detector` (which needs both submaps under one estimate)
cannot be used. Instead every earlier submap is ranked by appearance alone (tiny-image descriptors,
best view pair), and the best ``max_reprojection_checks`` are verified exactly as loops are (ORB
matches lifted to 3D, RANSAC, ``min_inliers`` and ``min_inlier_ratio``). The verified loop with the
most inliers wins. :func:`refine_rigid` then refines its transform by point-to-plane ICP between the
dense point maps (RGB-D: metric depth), starting from the RANSAC estimate (numpy + OpenCV's k-d
tree: no extra dependency).
"""

from __future__ import annotations

import numpy as np

from gsslam.config import LoopConfig
from gsslam.geometry import make_T, so3_exp
from gsslam.loop.appearance import appearance_overlap
from gsslam.loop.types import LoopCandidate, LoopConstraint, SubmapRecord
from gsslam.loop.verification import verify_candidate
from gsslam.types import SubmapEncoding


def relocalize(
    rec_i: SubmapRecord,
    earlier: list[SubmapRecord],
    cfg: LoopConfig,
    mode: str,
    rng: np.random.Generator,
) -> LoopConstraint | None:
    """The verified constraint between ``rec_i`` and the best of ``earlier`` (another chain), or None."""
    loops = verified_against(rec_i, earlier, cfg, mode, rng)
    return loops[0] if loops else None


def verified_against(
    rec_i: SubmapRecord,
    earlier: list[SubmapRecord],
    cfg: LoopConfig,
    mode: str,
    rng: np.random.Generator,
) -> list[LoopConstraint]:
    """Every verified constraint between ``rec_i`` and the ``max_reprojection_checks`` submaps of
    ``earlier`` that look most alike, most inliers first."""
    ranked = []
    for rec_m in earlier:
        app = appearance_overlap(rec_i.appearance, rec_m.appearance)  # [V_i, V_m]
        if app.size:
            ranked.append((float(app.max()), rec_m, app))
    ranked.sort(key=lambda r: -r[0])
    found: list[LoopConstraint] = []
    for score, rec_m, app in ranked[: cfg.max_reprojection_checks]:
        flat = np.argsort(-app, axis=None)
        pairs = tuple((int(a), int(b)) for a, b in zip(*np.unravel_index(flat, app.shape)))
        cand = LoopCandidate(rec_i.submap_id, rec_m.submap_id, 0.0, score, score, pairs)
        loop = verify_candidate(cand, rec_i, rec_m, cfg, mode, rng).loop
        if loop is not None:
            found.append(loop)
    return sorted(found, key=lambda lc: -len(lc))  # stable: ties keep the appearance order


def local_points(enc: SubmapEncoding, voxel: float) -> np.ndarray:  # -> [N, 3] submap-local
    """Every finite point of the submap's point maps in its local frame, one per ``voxel`` cell."""
    pts = []
    for T, P in zip(enc.T_local_cam, enc.points_cam):
        p = P.reshape(-1, 3)
        p = p[np.isfinite(p).all(axis=1)]
        pts.append(p @ T[:3, :3].T + T[:3, 3])
    pts = np.concatenate(pts) if pts else np.zeros((0, 3))
    if len(pts) == 0:
        return pts
    _, keep = np.unique(np.floor(pts / voxel).astype(np.int64), axis=0, return_index=True)
    return pts[np.sort(keep)]


def _normals(points: np.ndarray, index, k: int = 30, chunk: int = 20000) -> np.ndarray:  # [N, 3] -> [N, 3]
    """Unit surface normals by PCA of each point's ``k`` nearest neighbours.

    In chunks of ``chunk`` points: the neighbourhoods of a whole chain at once ([N, k, 3] twice) took
    12 GB on a 640-frame relocalization; the search is exact, so chunks give the same normals.
    """
    out = np.empty((len(points), 3))
    for a in range(0, len(points), chunk):
        p = points[a : a + chunk]
        idx, _ = index.knnSearch(p.astype(np.float32), k, params={"checks": -1})
        nb = points[idx]  # [n, k, 3]
        centred = nb - nb.mean(axis=1, keepdims=True)
        _, vecs = np.linalg.eigh(np.einsum("nki,nkj->nij", centred, centred))
        out[a : a + chunk] = vecs[:, :, 0]  # eigenvector of the smallest eigenvalue
    return out


def refine_rigid(
    T_dst_src: np.ndarray,  # [4, 4] initial, maps src points onto dst points
    points_dst: np.ndarray,  # [N, 3]
    points_src: np.ndarray,  # [M, 3]
    max_distance: float,
    iterations: int = 30,
    with_scale: bool = False,
) -> tuple[np.ndarray, float]:
    """Point-to-plane ICP of ``points_src`` onto ``points_dst`` from ``T_dst_src``; returns the refined
    transform and its fitness (share of ``points_src`` with a partner within ``max_distance``).

    Exact nearest neighbours from OpenCV's single k-d tree (deterministic); each step solves the
    linearized point-to-plane least squares for a small rotation and translation, and with
    ``with_scale`` (Sim(3), two monocular chains) also a small log-scale ``sigma``: a moved point
    ``p`` becomes ``(1 + sigma) p + omega x p + t``, so its column is ``n . p``.
    """
    import cv2

    dst = np.asarray(points_dst, dtype=np.float64)
    src = np.asarray(points_src, dtype=np.float64)
    index = cv2.flann_Index(dst.astype(np.float32), {"algorithm": 4, "leaf_max_size": 10})  # single kd-tree
    normals = _normals(dst, index)
    T = np.asarray(T_dst_src, dtype=np.float64).copy()
    ok = np.zeros(len(src), dtype=bool)
    for _ in range(iterations):
        moved = src @ T[:3, :3].T + T[:3, 3]
        idx, d2 = index.knnSearch(moved.astype(np.float32), 1, params={"checks": -1})
        idx, dist = idx[:, 0], np.sqrt(d2[:, 0])
        ok = dist < max_distance
        if ok.sum() < 6:
            break
        p, q, n = moved[ok], dst[idx[ok]], normals[idx[ok]]
        A = np.concatenate([np.cross(p, n), n], axis=1)  # [K, 6]: d(residual)/d(omega, t)
        if with_scale:
            A = np.concatenate([A, np.einsum("ki,ki->k", p, n)[:, None]], axis=1)  # [K, 7]: and sigma
        b = np.einsum("ki,ki->k", q - p, n)
        x = np.linalg.lstsq(A, b, rcond=None)[0]
        dT = make_T(so3_exp(x[:3]), x[3:6], float(np.exp(x[6])) if with_scale else 1.0)
        T = dT @ T
        if np.linalg.norm(x) < 1e-7:
            break
    moved = src @ T[:3, :3].T + T[:3, 3]
    _, d2 = index.knnSearch(moved.astype(np.float32), 1, params={"checks": -1})
    return T, float(np.mean(np.sqrt(d2[:, 0]) < max_distance))
