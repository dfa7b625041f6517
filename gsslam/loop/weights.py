"""The weight of a mono loop factor: per-point sigma of a verified loop's point pairs, in its own units.

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
``|T_i_m X_m - X_i|`` under the fitted Sim(3), floored at ``loop.mono_sigma_min_rel`` x the inlier
distance (a loop of few, very close points must not pin the graph), in submap-i units; the loop
factor then measures its residual in submap-i units too (:mod:`gsslam.factors.loop_points`). A
strong loop in world units pulls the chain's scale down: every world-unit residual shrinks with
the submaps' scales. Measured on teddy forward-backward-forward (mono, 28 loops): the inlier-RMS
sigma on world-unit residuals shrank the trajectory 2.7x (Sim(3) alignment scale 0.84 -> 2.26,
ATE 1.37 -> 44 cm).
"""

from __future__ import annotations

import numpy as np

from gsslam.config import LoopConfig
from gsslam.geometry import transform_points
from gsslam.loop.types import LoopConstraint


def inlier_rms(loop: LoopConstraint) -> float:
    """RMS of ``|T_i_m X_m - X_i|`` over the loop's point pairs (submap-i units)."""
    d = transform_points(loop.T_i_m, loop.X_m) - loop.X_i  # [N, 3]
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1))))


def loop_point_sigma(loop: LoopConstraint, mode: str, cfg: LoopConfig) -> float | None:
    """Mono: per-point sigma of the loop in submap-i units, for a loop factor in those units
    (``SubmapGraph.add_loop(..., sigma, local_units=True)``). None: the graph's default, a world-unit
    factor with ``graph.loop_sigma_m`` (RGB-D, or mono with ``loop.mono_sigma_from_residual=false``)."""
    if mode != "mono" or not cfg.mono_sigma_from_residual:
        return None
    return float(max(inlier_rms(loop), cfg.mono_sigma_min_rel * loop.threshold))
