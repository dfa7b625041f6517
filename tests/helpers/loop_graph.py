"""A small least-squares over submap transforms (test stand-in for the pipeline's graph).

Adjacency: a between factor per consecutive pair with the (drifted) estimated relative transform;
loops: a between factor ``T_i_m`` per loop constraint; a prior fixes submap 0. Pose3 for RGB-D,
Similarity3 for mono. Solved in batch with Levenberg-Marquardt.
"""

from __future__ import annotations

import gtsam
import numpy as np

from gsslam.geometry import invert_T, umeyama


def _sim3(T: np.ndarray) -> gtsam.Similarity3:
    """Our ``[[s R, t], [0, 1]]`` -> GTSAM's Similarity3, which maps x -> s (R x + t')."""
    s = float(np.cbrt(np.linalg.det(T[:3, :3])))
    return gtsam.Similarity3(gtsam.Rot3(T[:3, :3] / s), T[:3, 3] / s, s)


def _sim3_matrix(S: gtsam.Similarity3) -> np.ndarray:
    M = S.matrix()  # [[R, t'], [0, 1/s]]
    return M / M[3, 3]


def optimise(
    est: dict[int, np.ndarray], loops: dict, mono: bool, loop_sigma: float = 0.002
) -> dict[int, np.ndarray]:
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    ids = sorted(est)
    if mono:
        dim, wrap, between, prior = 7, _sim3, gtsam.BetweenFactorSimilarity3, gtsam.PriorFactorSimilarity3
        insert, get = values.insert, lambda v, k: _sim3_matrix(v.atSimilarity3(k))
    else:
        dim, wrap, between, prior = (
            6,
            lambda T: gtsam.Pose3(T),
            gtsam.BetweenFactorPose3,
            gtsam.PriorFactorPose3,
        )
        insert, get = values.insert, lambda v, k: v.atPose3(k).matrix()
    odo = gtsam.noiseModel.Isotropic.Sigma(dim, 0.01)
    lp = gtsam.noiseModel.Isotropic.Sigma(dim, loop_sigma)
    graph.add(prior(ids[0], wrap(est[ids[0]]), gtsam.noiseModel.Isotropic.Sigma(dim, 1e-6)))
    for a, b in zip(ids[:-1], ids[1:]):
        graph.add(between(a, b, wrap(invert_T(est[a]) @ est[b]), odo))
    for loop in loops.values():
        graph.add(between(loop.i, loop.m, wrap(loop.T_i_m), lp))
    for k in ids:
        insert(k, wrap(est[k]))
    result = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    return {k: get(result, k) for k in ids}


def keyframe_positions(world: dict[int, np.ndarray], encodings) -> np.ndarray:  # [N, 3]
    return np.array([(world[s] @ T)[:3, 3] for s, enc in enumerate(encodings) for T in enc.T_local_cam])


def ate(est_positions: np.ndarray, gt_positions: np.ndarray, with_scale: bool) -> float:
    T = umeyama(est_positions, gt_positions, with_scale=with_scale)
    aligned = est_positions @ T[:3, :3].T + T[:3, 3]
    return float(np.sqrt(np.mean(np.sum((aligned - gt_positions) ** 2, axis=1))))
