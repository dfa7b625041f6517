"""The weight of a loop factor: per-point sigma of a verified loop's point pairs, in world units.

A loop enters the graph as one point factor ``S(i)(X_i) ~ S(m)(X_m)`` whose residual is in world
units (:meth:`gsslam.graph.submap_graph.SubmapGraph.add_loop`). In RGB-D the world is metric and
``graph.loop_sigma_m`` (5 cm) equals the loop's inlier distance (``loop.inlier_threshold_m``). In
mono the world unit is the first frame's median depth, so the same 0.05 is 5 % of the scene depth:
2.5x the mono inlier distance (``loop.inlier_threshold_rel`` = 2 % of depth) and 4-6x the RMS of a
verified loop's inliers. Weighted that way, a correct loop is too weak to bend the chain of flow
factors; on the synthetic 800-frame loop it moved the chain along its softest directions and made
the trajectory worse than no loop at all (a loop replaced by its exact ground-truth value did the
same; docs/results.md, "Mono loops, session 5").

Mono therefore uses the loop's *measured* accuracy: the RMS of the RANSAC inliers' residuals
``|T_i_m X_m - X_i|`` under the fitted Sim(3) (submap-i units), floored at
``loop.mono_sigma_min_rel`` x the inlier distance (a loop of few, very close points must not pin
the graph), times the scale of ``S(i)`` (submap-i units -> world units).
"""

from __future__ import annotations

import numpy as np

from gsslam.config import LoopConfig
from gsslam.geometry import split_sim3, transform_points
from gsslam.loop.types import LoopConstraint


def inlier_rms(loop: LoopConstraint) -> float:
    """RMS of ``|T_i_m X_m - X_i|`` over the loop's point pairs (submap-i units)."""
    d = transform_points(loop.T_i_m, loop.X_m) - loop.X_i  # [N, 3]
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1))))


def loop_point_sigma(
    loop: LoopConstraint, T_world_local_i: np.ndarray, mode: str, cfg: LoopConfig
) -> float | None:
    """Per-point sigma (world units) for the loop's point factor; None: the graph's default
    (``graph.loop_sigma_m``: RGB-D, or mono with ``loop.mono_sigma_from_residual=false``).

    ``T_world_local_i`` [4, 4]: the current Sim(3) estimate of submap ``loop.i``.
    """
    if mode != "mono" or not cfg.mono_sigma_from_residual:
        return None
    per_point = max(inlier_rms(loop), cfg.mono_sigma_min_rel * loop.threshold)  # submap-i units
    return float(per_point * split_sim3(T_world_local_i)[2])
