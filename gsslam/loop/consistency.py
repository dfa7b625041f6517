"""Robustness of loop closure and propagation of the correction.

- :func:`drift_gate` (before the graph sees a loop): the loop's ``T_i_m`` may disagree with the
  current estimate by no more than drift can explain: the RMS displacement of the loop points
  must stay below ``max_drift_ratio`` times the path length between the two submaps, and the
  rotation difference below ``max_rot_discrepancy_deg``.
- :func:`check_loops` (after the graph update): a loop whose residual under the optimised
  transforms is still large was fighting the adjacency constraints, i.e. it is wrong; the
  pipeline removes its factor (``SubmapGraph.remove_factor``) and updates again.
- :func:`pairwise_conflicts` (after the update, with several loops): two loops are consistent
  when each predicts the other through the adjacency chain (the submap-to-submap transforms
  recorded before any loop moved them) within what drift explains; a loop in conflict with
  most others is wrong even if the graph managed to satisfy it by bending the chain.
- :func:`propagate_correction`: per-submap ``T_new_old`` that moves camera poses and Gaussians
  of each submap with its optimised transform (both sides of every loop move: bidirectional).
"""

from __future__ import annotations

import logging
from collections.abc import Hashable, Mapping

import numpy as np

from gsslam.config import LoopConfig
from gsslam.geometry import invert_T, so3_log, split_sim3, transform_points
from gsslam.loop.types import LoopConstraint, LoopError

log = logging.getLogger(__name__)


def relative(poses: Mapping[int, np.ndarray], i: int, m: int) -> np.ndarray:
    """``T_i_m`` of the estimate: submap-m local -> submap-i local."""
    if i not in poses or m not in poses:
        raise LoopError(
            f"no world transform for submap {i if i not in poses else m}; pass every submap's T_world_local"
        )
    return invert_T(poses[i]) @ poses[m]


def rotation_deg(T_a: np.ndarray, T_b: np.ndarray) -> float:
    Ra, _, _ = split_sim3(T_a)
    Rb, _, _ = split_sim3(T_b)
    return float(np.degrees(np.linalg.norm(so3_log(Ra.T @ Rb))))


def loop_residual(loop: LoopConstraint, T_i_m: np.ndarray) -> float:
    """RMS of ``|T_i_m X_m - X_i|`` over the loop's point pairs (submap-i units)."""
    return float(np.sqrt(np.mean(np.sum((transform_points(T_i_m, loop.X_m) - loop.X_i) ** 2, axis=1))))


def path_length(poses: Mapping[int, np.ndarray], i: int, m: int) -> float:
    """Length of the chain of submap origins from m to i, in submap-i local units."""
    ids = sorted(k for k in poses if min(i, m) <= k <= max(i, m))
    origins = np.array([poses[k][:3, 3] for k in ids])
    length = float(np.linalg.norm(np.diff(origins, axis=0), axis=1).sum()) if len(ids) > 1 else 0.0
    return length / split_sim3(poses[i])[2]


def drift_gate(loop: LoopConstraint, poses: Mapping[int, np.ndarray], cfg: LoopConfig) -> tuple[bool, str]:
    """Is the loop's disagreement with the current estimate explainable by drift?"""
    T_est = relative(poses, loop.i, loop.m)
    disp = loop_residual(loop, T_est)
    path = max(path_length(poses, loop.i, loop.m), 1e-9)
    rot = rotation_deg(T_est, loop.T_i_m)
    if disp > cfg.max_drift_ratio * path + loop.threshold:
        return False, f"displacement {disp:.3f} > {cfg.max_drift_ratio} x path {path:.3f}"
    if rot > cfg.max_rot_discrepancy_deg:
        return False, f"rotation disagreement {rot:.1f} deg > {cfg.max_rot_discrepancy_deg}"
    return True, f"displacement {disp:.3f} over path {path:.3f}, rotation {rot:.1f} deg"


def check_loops(
    loops: Mapping[Hashable, LoopConstraint],
    poses: Mapping[int, np.ndarray],
    cfg: LoopConfig,
) -> list[Hashable]:
    """Handles of loops the optimised ``poses`` (submap id -> T_world_local) do not satisfy.

    A loop is rejected when its residual RMS exceeds ``max_residual_factor`` times its inlier
    threshold, or its ``T_i_m`` differs from the estimate by more than
    ``max_rot_discrepancy_deg``. Returned worst first (by residual / threshold); after removing
    them the pipeline should update the graph and may call this again.
    """
    bad = []
    for handle, loop in loops.items():
        T_est = relative(poses, loop.i, loop.m)
        r = loop_residual(loop, T_est) / max(loop.threshold, 1e-12)
        rot = rotation_deg(T_est, loop.T_i_m)
        if r > cfg.max_residual_factor or rot > cfg.max_rot_discrepancy_deg:
            log.info(
                "loop %d-%d rejected after optimisation: residual %.1f x threshold, rotation %.1f deg",
                loop.i,
                loop.m,
                r,
                rot,
            )
            bad.append((r, handle))
    bad.sort(key=lambda x: -x[0])
    return [h for _, h in bad]


def reject_inconsistent(
    loops: Mapping[Hashable, LoopConstraint], odometry: Mapping[int, np.ndarray], cfg: LoopConfig
) -> list[Hashable]:
    """Greedily drop the loop with the most conflicts while it conflicts with at least half the rest."""
    live = dict(loops)
    out = []
    while len(live) >= 2:
        conf = pairwise_conflicts(live, odometry, cfg)
        worst = max(conf, key=lambda h: (len(conf[h]), -len(live[h]) * live[h].inlier_ratio))
        if not conf[worst] or 2 * len(conf[worst]) < len(live) - 1:
            break
        if len(live) == 2:  # two loops disagree: keep the better supported one
            worst = min(live, key=lambda h: len(live[h]) * live[h].inlier_ratio)
        log.info(
            "loop %d-%d rejected: inconsistent with %d other loops",
            live[worst].i,
            live[worst].m,
            len(conf[worst]),
        )
        out.append(worst)
        del live[worst]
    return out


def chain(odometry: Mapping[int, np.ndarray], a: int, b: int) -> tuple[np.ndarray, float]:
    """``T_a_b`` composed from adjacency links, and the chain's length (in submap-a units).

    ``odometry``: submap id k -> ``T_{prev}_k`` of the link from the submap before k to k,
    for consecutive ids (the detector records them).
    """
    ids = sorted(k for k in odometry if min(a, b) < k <= max(a, b))
    T = np.eye(4)
    length = 0.0
    for k in ids:  # T_lo_hi = L_{lo+1} ... L_hi; lengths summed in submap-lo units
        length += split_sim3(T)[2] * float(np.linalg.norm(odometry[k][:3, 3]))
        T = T @ odometry[k]
    if a > b:
        length /= split_sim3(T)[2]
        T = invert_T(T)
    return T, length


def pairwise_conflicts(
    loops: Mapping[Hashable, LoopConstraint], odometry: Mapping[int, np.ndarray], cfg: LoopConfig
) -> dict[Hashable, set]:
    """For each loop, the loops it is inconsistent with (cycle test through the adjacency chain)."""
    items = list(loops.items())
    out: dict[Hashable, set] = {h: set() for h, _ in items}
    for x, (ha, a) in enumerate(items):
        for hb, b in items[x + 1 :]:
            T_ia_ib, len_i = chain(odometry, a.i, b.i)
            T_mb_ma, len_m = chain(odometry, b.m, a.m)
            pred = T_ia_ib @ b.T_i_m @ T_mb_ma  # T_ia_ma predicted by loop b
            s_b = split_sim3(T_ia_ib)[2]  # submap-b units -> submap-a units
            bound = (
                cfg.max_drift_ratio * (len_i + s_b * split_sim3(b.T_i_m)[2] * len_m)
                + a.threshold
                + s_b * b.threshold
            )
            if loop_residual(a, pred) > bound or rotation_deg(pred, a.T_i_m) > cfg.max_rot_discrepancy_deg:
                out[ha].add(hb)
                out[hb].add(ha)
    return out


def propagate_correction(
    old_poses: Mapping[int, np.ndarray],  # submap id -> [4, 4] T_world_local before the update
    new_poses: Mapping[int, np.ndarray],  # submap id -> [4, 4] after
) -> dict[int, np.ndarray]:
    """``T_new_old`` per submap present in both: ``X_world_new = T_new_old @ X_world_old``.

    Apply it to everything anchored in that submap (its keyframe poses ``T_world_cam`` and its
    Gaussians). For Sim(3) it carries the scale change too.
    """
    return {k: new_poses[k] @ invert_T(old_poses[k]) for k in old_poses if k in new_poses}
