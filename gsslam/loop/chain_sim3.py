"""The Sim(3) between two monocular chains, from the loops verified across them.

After a gap a monocular chain starts over with its own frame AND its own scale, so the rigid
placement used for RGB-D chains (:mod:`gsslam.loop.relocalize` + ICP) does not apply. Every loop
verified between a submap ``i`` of the new chain and a submap ``m`` of an earlier one
(:func:`gsslam.loop.relocalize.verified_against`, a Sim(3) RANSAC per submap pair) gives 3D point
pairs in the two submaps' local frames. Moved into their chains' frames by the submaps' current
Sim(3) estimates ``S_new(i)`` and ``S_old(m)``, the pairs of all such loops are pooled and one
Sim(3) ``T_old_new`` (``X_old ~ T_old_new X_new``) is fitted by Umeyama inside RANSAC, so the scale
rests on every verified point of every loop rather than on one submap pair.

The threshold is relative to the scene depth in the earlier chain's units
(``loop.inlier_threshold_rel`` x the median submap depth). Monocular point maps are noisy, so few
ORB matches survive across a gap (teddy: 24 of 228) and the sparse Sim(3) is only a start:
:func:`refine_dense` refines it by ICP with a scale term on the two chains' dense point maps and
verifies it there (the share of new points that meet the earlier surface). Numpy and OpenCV's
k-d tree: the caller decides what to do with the result
(:meth:`gsslam.slam.loop_stage.LoopStage.relocalize`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from gsslam.geometry import sim3_scale, split_sim3, transform_points, umeyama
from gsslam.loop.relocalize import local_points, refine_rigid
from gsslam.loop.types import LoopConstraint
from gsslam.loop.verification import ransac_transform

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ChainSim3:
    """``T_old_new`` [4, 4] Sim(3) maps new-chain points into the earlier chain's frame."""

    T_old_new: np.ndarray
    inliers: int  # pooled point pairs within the threshold
    pairs: int  # pooled point pairs in all
    loops: int  # verified submap pairs that contributed
    rms: float  # inlier residual, earlier-chain units

    @property
    def scale(self) -> float:
        return sim3_scale(self.T_old_new)


def pooled_pairs(
    loops: list[LoopConstraint],
    S_new: dict[int, np.ndarray],  # submap -> [4, 4] Sim(3) in the new chain
    S_old: dict[int, np.ndarray],  # submap -> [4, 4] Sim(3) in the earlier chain
) -> tuple[np.ndarray, np.ndarray]:  # -> X_new [N, 3], X_old [N, 3] in the chains' frames
    """The loops' inlier point pairs, each moved into its chain's frame."""
    X_new, X_old = [], []
    for lc in loops:
        X_new.append(transform_points(S_new[lc.i], lc.X_i))
        X_old.append(transform_points(S_old[lc.m], lc.X_m))
    if not X_new:
        return np.zeros((0, 3)), np.zeros((0, 3))
    return np.concatenate(X_new), np.concatenate(X_old)


def fit_chain_sim3(
    loops: list[LoopConstraint],
    S_new: dict[int, np.ndarray],
    S_old: dict[int, np.ndarray],
    threshold: float,  # earlier-chain units
    iterations: int,
    rng: np.random.Generator,
) -> ChainSim3 | None:
    """One Sim(3) from the pooled pairs of ``loops`` (None: fewer than 3 consistent pairs)."""
    X_new, X_old = pooled_pairs(loops, S_new, S_old)
    T, inl = ransac_transform(X_old, X_new, threshold, with_scale=True, iterations=iterations, rng=rng)
    if T is None:
        return None
    res = np.linalg.norm(transform_points(T, X_new[inl]) - X_old[inl], axis=1)
    return ChainSim3(T, int(inl.sum()), len(X_new), len(loops), float(np.sqrt(np.mean(res**2))))


def dense_points(encodings: list, poses: dict[int, np.ndarray], spacing: float) -> np.ndarray:
    """Every submap's point maps in its chain's frame (``poses``: submap -> Sim(3)), about one point
    per ``spacing`` (chain units): [N, 3]."""
    out = [np.zeros((0, 3))]
    for k, S in poses.items():
        out.append(transform_points(S, local_points(encodings[k], spacing / sim3_scale(S))))
    return np.concatenate(out)


def refine_dense(
    fit: ChainSim3,
    points_old: np.ndarray,  # [N, 3] earlier chain's frame
    points_new: np.ndarray,  # [M, 3] new chain's frame
    threshold: float,  # earlier-chain units
    min_fitness: float,
    max_rot_deg: float = 30.0,
    max_log_scale: float = 0.4,
) -> tuple[ChainSim3 | None, float | None]:
    """``fit`` refined on the dense point maps, and its fitness; ``(None, fitness)`` when the two
    chains' surfaces do not meet.

    Point-to-point ICP with scale (:func:`icp_sim3`, gate ``threshold`` then half of it), then
    point-to-plane ICP with a scale term (:func:`gsslam.loop.relocalize.refine_rigid`) at half the
    threshold. On teddy the sparse estimate is 20 deg / 28 % off where ICP lands within 4 deg / 15 %
    (docs/loop_closure.md), so ICP may move it far; it must stay within ``max_rot_deg`` and
    ``max_log_scale`` of it (a sanity bound, not a closeness test) and bring at least ``min_fitness``
    of the new points within half the threshold of the earlier surface (the dense verification).
    """
    if len(points_old) < 100 or len(points_new) < 100:
        return None, None
    T0 = fit.T_old_new
    T, _ = icp_sim3(T0, points_old, points_new, threshold)
    T, _ = icp_sim3(T, points_old, points_new, threshold / 2)
    T, fitness = refine_rigid(T, points_old, points_new, threshold / 2, with_scale=True)
    R0, _, s0 = split_sim3(T0)
    R1, _, s1 = split_sim3(T)
    angle = np.degrees(np.arccos(np.clip((np.trace(R0.T @ R1) - 1) / 2, -1.0, 1.0)))
    log.debug("chain Sim(3) ICP: fitness %.2f, moved %.1f deg, scale x%.3f", fitness, angle, s1 / s0)
    if fitness < min_fitness or angle > max_rot_deg or abs(np.log(s1 / s0)) > max_log_scale:
        return None, fitness
    return ChainSim3(T, fit.inliers, fit.pairs, fit.loops, fit.rms), fitness


def icp_sim3(
    T_dst_src: np.ndarray,  # [4, 4] initial Sim(3)
    points_dst: np.ndarray,  # [N, 3]
    points_src: np.ndarray,  # [M, 3]
    max_distance: float,
    iterations: int = 30,
) -> tuple[np.ndarray, float]:
    """Point-to-point ICP with scale: nearest neighbours within ``max_distance`` (exact, OpenCV's
    single k-d tree), then Umeyama Sim(3) on the pairs, repeated; returns the transform and its
    fitness (share of ``points_src`` with a partner within ``max_distance``)."""
    import cv2

    dst = np.asarray(points_dst, dtype=np.float64)
    src = np.asarray(points_src, dtype=np.float64)
    index = cv2.flann_Index(dst.astype(np.float32), {"algorithm": 4, "leaf_max_size": 10})
    T = np.asarray(T_dst_src, dtype=np.float64).copy()
    for _ in range(iterations):
        moved = transform_points(T, src)
        idx, d2 = index.knnSearch(moved.astype(np.float32), 1, params={"checks": -1})
        ok = np.sqrt(d2[:, 0]) < max_distance
        if ok.sum() < 6:
            break
        T_new = umeyama(src[ok], dst[idx[ok, 0]], with_scale=True)
        step = np.abs(T_new - T).max()
        T = T_new
        if step < 1e-7:
            break
    _, d2 = index.knnSearch(transform_points(T, src).astype(np.float32), 1, params={"checks": -1})
    return T, float(np.mean(np.sqrt(d2[:, 0]) < max_distance))
