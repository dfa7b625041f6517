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

Session 6 (``loop.mono_sigma_ray``, default): one isotropic sigma treats the depth error of a mono point
(along its viewing ray, 1.3-4x the error across it in the loops measured) like its pixel error. A
depth distortion of the point maps then tilts the loop's Sim(3), and many loops so weighted pulled the
teddy forward-backward-forward run off by several degrees (docs/results.md, "Mono loops, session 6").
The loop's residuals are therefore split along ``u = X_i / |X_i|`` (the ray from submap i's origin) and
across it: ``sigma_ray`` = RMS of the along-ray parts, ``sigma_perp`` = RMS per axis of the across
parts, both floored like the isotropic sigma, for :mod:`gsslam.factors.loop_rays`; with these per-axis
sigmas a loop the graph meets within its own noise has chi-square ~3N, and a DCS kernel
(``loop.mono_dcs_phi`` x 3N) lowers the weight of a loop the graph cannot meet so.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gsslam.config import LoopConfig
from gsslam.geometry import transform_points
from gsslam.loop.extent import lateral_extent_rel
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


@dataclass(frozen=True)
class LoopWeight:
    """How a mono loop enters the graph: ``sigma`` (along the ray, or isotropic when ``sigma_perp`` is
    None) and ``sigma_perp`` (across the ray, per axis), submap-i units; ``dcs_phi`` its kernel (0: none)."""

    sigma: float
    sigma_perp: float | None = None
    dcs_phi: float = 0.0


def ray_sigmas(loop: LoopConstraint) -> tuple[float, float]:
    """(RMS of the residuals ``X_i - T_i_m X_m`` along ``X_i``'s rays, RMS per axis across them)."""
    d = loop.X_i - transform_points(loop.T_i_m, loop.X_m)  # [N, 3]
    u = loop.X_i / np.maximum(np.linalg.norm(loop.X_i, axis=1, keepdims=True), 1e-12)  # [N, 3]
    along = np.sum(d * u, axis=1)  # [N]
    across = d - along[:, None] * u  # [N, 3], 2 dof per point
    return float(np.sqrt(np.mean(along**2))), float(np.sqrt(np.mean(np.sum(across**2, axis=1)) / 2))


def loop_weight(loop: LoopConstraint, mode: str, cfg: LoopConfig) -> LoopWeight | None:
    """Mono: the loop's weight in submap-i units (``loop.mono_sigma_ray``: along / across the rays with
    a DCS kernel; else :func:`loop_point_sigma`). None: RGB-D, or the old world-unit factor."""
    sigma = loop_point_sigma(loop, mode, cfg)
    if sigma is None:
        return None
    f = extent_factor(loop, cfg)
    if not cfg.mono_sigma_ray:
        return LoopWeight(f * sigma)
    floor = cfg.mono_sigma_min_rel * loop.threshold
    s_ray, s_perp = ray_sigmas(loop)
    return LoopWeight(f * max(s_ray, floor), f * max(s_perp, floor), cfg.mono_dcs_phi)


def extent_factor(loop: LoopConstraint, cfg: LoopConfig) -> float:
    """``max(1, loop.mono_extent_sigma / extent)``: a loop whose points lie on a narrow strip turns with
    the point maps' correlated depth error, not with its inlier noise (:mod:`gsslam.loop.extent`); 1 when
    the key is 0."""
    if cfg.mono_extent_sigma <= 0:
        return 1.0
    return max(1.0, cfg.mono_extent_sigma / max(lateral_extent_rel(loop.X_i), 1e-9))
