"""Submap-level errors against ground truth: how good a loop or a submap pose can be.

A submap holds its keyframes at fixed local poses ``T_local_cam`` (from the encoder); the graph only
moves the submap's frame ``T_world_local``. With ground-truth camera poses ``T_world_cam`` of its
keyframes, :func:`best_submap_pose` is the rigid ``T_world_local`` that puts those keyframes closest to
ground truth: the best any submap-level correction (loops included) can do. A loop's relative pose
``T_i_m`` (submap-m local -> submap-i local) is then judged against the relative pose of the two
submaps at their best poses (:func:`loop_reference`), and :func:`pose_difference` gives translation and
rotation of the disagreement. Pure numpy, no files (docs/loop_closure.md, "Auditing loops").
"""

from __future__ import annotations

import numpy as np

from gsslam.eval import EvalError
from gsslam.geometry import invert_T, umeyama

AHEAD_M = 0.5  # a point this far ahead of each camera ties the orientation in the fit


def best_submap_pose(T_local_cam: np.ndarray, T_world_cam: np.ndarray, ahead: float = AHEAD_M) -> np.ndarray:
    """Rigid ``T_world_local`` [4, 4] minimising the distance of the submap's keyframes to ground truth.

    ``T_local_cam``: [V, 4, 4] the keyframes in the submap's frame (rigid, metres); ``T_world_cam``:
    [V, 4, 4] their ground-truth poses. The fit uses each camera centre and the point ``ahead`` metres
    along its optical axis, so one keyframe fixes the orientation too.
    """
    L, G = np.asarray(T_local_cam, float), np.asarray(T_world_cam, float)
    if L.ndim != 3 or L.shape[1:] != (4, 4) or L.shape != G.shape or len(L) == 0:
        raise EvalError(f"need matching non-empty [V, 4, 4] poses, got {L.shape} and {G.shape}")
    axis = np.array([0.0, 0.0, ahead])
    src = np.concatenate([L[:, :3, 3], L[:, :3, :3] @ axis + L[:, :3, 3]])  # [2V, 3]
    dst = np.concatenate([G[:, :3, 3], G[:, :3, :3] @ axis + G[:, :3, 3]])  # [2V, 3]
    return umeyama(src, dst, with_scale=False)


def loop_reference(T_world_local_i: np.ndarray, T_world_local_m: np.ndarray) -> np.ndarray:
    """``T_i_m`` [4, 4] of two submaps at the given (best) poses: the value a loop should measure."""
    return invert_T(np.asarray(T_world_local_i, float)) @ np.asarray(T_world_local_m, float)


def pose_difference(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """``(translation m, rotation deg)`` of ``T_b^-1 T_a`` for rigid [4, 4] transforms."""
    D = invert_T(np.asarray(T_b, float)) @ np.asarray(T_a, float)
    cos = np.clip((np.trace(D[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.linalg.norm(D[:3, 3])), float(np.degrees(np.arccos(cos)))
