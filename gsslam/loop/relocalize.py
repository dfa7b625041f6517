"""Re-localization across chains: place a new chain's submap against an earlier chain's submaps.

After tracking loss the new chain has its own graph and no pose prior relative to the earlier map,
so the overlap test of :mod:`gsslam.loop.detector` (which needs both submaps under one estimate)
cannot be used. Instead every earlier submap is ranked by appearance alone (tiny-image descriptors,
best view pair), and the best ``max_reprojection_checks`` are verified exactly as loops are (ORB
matches lifted to 3D, RANSAC, ``min_inliers`` and ``min_inlier_ratio``). The verified loop with the
most inliers wins. :func:`refine_rigid` then refines its transform by point-to-plane ICP between the
two submaps' dense point maps (RGB-D: metric depth), starting from the RANSAC estimate.
"""

from __future__ import annotations

import numpy as np

from gsslam.config import LoopConfig
from gsslam.loop.appearance import appearance_overlap
from gsslam.loop.types import LoopCandidate, LoopConstraint, SubmapRecord
from gsslam.loop.verification import verify
from gsslam.types import SubmapEncoding


def relocalize(
    rec_i: SubmapRecord,
    earlier: list[SubmapRecord],
    cfg: LoopConfig,
    mode: str,
    rng: np.random.Generator,
) -> LoopConstraint | None:
    """The verified constraint between ``rec_i`` and the best of ``earlier`` (another chain), or None."""
    ranked = []
    for rec_m in earlier:
        app = appearance_overlap(rec_i.appearance, rec_m.appearance)  # [V_i, V_m]
        if app.size:
            ranked.append((float(app.max()), rec_m, app))
    ranked.sort(key=lambda r: -r[0])
    best: LoopConstraint | None = None
    for score, rec_m, app in ranked[: cfg.max_reprojection_checks]:
        flat = np.argsort(-app, axis=None)
        pairs = tuple((int(a), int(b)) for a, b in zip(*np.unravel_index(flat, app.shape)))
        cand = LoopCandidate(rec_i.submap_id, rec_m.submap_id, 0.0, score, score, pairs)
        loop = verify(cand, rec_i, rec_m, cfg, mode, rng)
        if loop is not None and (best is None or len(loop) > len(best)):
            best = loop
    return best


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


def refine_rigid(
    T_i_m: np.ndarray,  # [4, 4] initial, maps submap-m local points to submap-i local
    points_i: np.ndarray,  # [N, 3]
    points_m: np.ndarray,  # [M, 3]
    max_distance: float,
    iterations: int = 30,
) -> tuple[np.ndarray, float]:
    """Point-to-plane ICP of ``points_m`` onto ``points_i`` from ``T_i_m``; returns (T_i_m, fitness).

    ``fitness``: share of ``points_m`` with a partner within ``max_distance`` after refinement.
    """
    import open3d as o3d  # only when chains are re-localized

    src, dst = o3d.geometry.PointCloud(), o3d.geometry.PointCloud()
    src.points = o3d.utility.Vector3dVector(np.asarray(points_m, dtype=np.float64))
    dst.points = o3d.utility.Vector3dVector(np.asarray(points_i, dtype=np.float64))
    dst.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=3 * max_distance, max_nn=30))
    res = o3d.pipelines.registration.registration_icp(
        src,
        dst,
        max_distance,
        np.asarray(T_i_m, dtype=np.float64),
        o3d.pipelines.registration.TransformationEstimationPointToPlane(),
        o3d.pipelines.registration.ICPConvergenceCriteria(max_iteration=iterations),
    )
    return np.asarray(res.transformation), float(res.fitness)
