"""Per-submap translation stretch in the mono graph (``graph.mono_translation_stretch``).

A mono submap's one Sim(3) scale serves its depth and its local keyframe translations together, but the
two disagree by 6-7 % (std of log) per submap (docs/results.md, "Mono scale chain, session 10"). With the
option on, each mono submap ``i`` gets a 1-D variable ``t{i}`` (a log-stretch, ``Vector`` of size 1,
prior mean 0 and std ``graph.mono_stretch_sigma``) that scales its local keyframe translations only::

    T_world_cam(i, j) = rigid(S(i) [R_j, exp(t_i) t_j])       the point maps (depth) are not stretched

The factors that read a local translation carry the stretch of its submap
(:mod:`gsslam.factors.stretch`): the rigid alignment (frame K of submap i-1: ``t{i-1}``), the adjacency
points of the shared frame (their offset is that frame's camera in submap i-1), the cross-submap
flow factors (``L_a``, ``L_b``) and the mono ray-point loops (each point's offset is the camera of the
keyframe it was seen in). Not stretched (they stay on ``S(i)`` with the unstretched local pose):
map registrations, keyframe pose priors and loops without their points' keyframes (mono ray-point
loops carry them: ``LoopConstraint.view_i`` / ``view_m``). The scale factor
compares depths only. A keyframe's pose (and so every frame's, through its keyframe) is read with the
stretch. RGB-D graphs never get the variable.
"""

from __future__ import annotations

import gtsam
import numpy as np

from gsslam.factors.stretch import read_stretch, stretched
from gsslam.graph.factor_specs import FactorSpec, spec
from gsslam.graph.keys import submap_key, user_key

STRETCH_CHAR = "t"


def stretch_key(i: int) -> int:
    """The stretch variable ``t{i}`` of submap ``i``."""
    return user_key(STRETCH_CHAR, i)


def prior_spec(i: int, sigma: float) -> FactorSpec:
    return spec("stretch_prior", stretch_key(i), float(sigma))


def initial_value() -> np.ndarray:  # [1]
    return np.zeros(1)


def alignment_spec(i: int, Z: np.ndarray, rot_sigma: float, trans_sigma: float) -> FactorSpec:
    """Submap i chained to i-1 through frame K of i-1 (local pose ``Z``, stretched by ``t{i-1}``)."""
    a, b = submap_key(i - 1), submap_key(i)
    return spec("stretched_alignment", a, b, stretch_key(i - 1), Z, rot_sigma, trans_sigma)


def adjacency_spec(i: int, X_cam: np.ndarray, Z: np.ndarray, X_b: np.ndarray, sigma: float) -> FactorSpec:
    """Shared-frame points: ``X_cam`` [N, 3] in frame K's camera (submap i-1), ``X_b`` [N, 3] in submap i."""
    P_a = X_cam @ Z[:3, :3].T
    return spec("stretched_point", submap_key(i - 1), submap_key(i), stretch_key(i - 1), P_a, Z[:3, 3].copy(),
                X_b, float(sigma))  # fmt: skip


def flow_spec(ia: int, ib: int, uv_src, depth_src, uv_tgt, K, weight, L_a, L_b, kwargs: dict) -> FactorSpec:
    """A cross-submap flow factor with both local poses stretched (``kwargs``: the flow noise settings)."""
    return spec(
        "stretched_flow", submap_key(ia), submap_key(ib), stretch_key(ia), stretch_key(ib),
        uv_src, depth_src, uv_tgt, K, weight=weight, L_a=L_a, L_b=L_b, **kwargs,
    )  # fmt: skip


def ray_spec(i: int, m: int, X_i, o_i, X_m, o_m, sigma_ray, sigma_perp, dcs_phi: float) -> FactorSpec:
    """A mono loop (ray-point factor) with both submaps' points on their stretches: ``X`` [N, 3] local
    points, ``o`` [N, 3] the local translation of the keyframe each was seen in."""
    return spec(
        "stretched_ray_point", submap_key(i), submap_key(m), stretch_key(i), stretch_key(m),
        X_i - o_i, o_i, X_m - o_m, o_m, sigma_ray, sigma_perp, dcs_phi=dcs_phi,
    )  # fmt: skip


def stretch_of(values: gtsam.Values, i: int) -> float:
    """Submap i's log-stretch in ``values`` (0 when it has none)."""
    k = stretch_key(i)
    return read_stretch(values, k) if values.exists(k) else 0.0


def local_pose(values: gtsam.Values, i: int, L: np.ndarray) -> np.ndarray:
    """The local pose ``L`` [4, 4] of a keyframe of submap i with its stretch applied."""
    return stretched(L, stretch_of(values, i))
