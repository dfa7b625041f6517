"""gtsam's stereo factors through our Backend (gtsam's KITTI stereo VO data), alone and mixed with ours."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import gtsam
import numpy as np
import pytest

from gsslam.factors import make_point_factor
from gsslam.graph.backend import Backend
from gsslam.graph.keys import keyframe_key, user_key

_spec = importlib.util.spec_from_file_location(
    "swap_in_sensors", Path(__file__).parents[2] / "examples" / "swap_in_sensors.py"
)
_example = sys.modules[_spec.name] = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_example)  # examples/ is runnable scripts, not a package
load_stereo_vo = _example.load_stereo_vo
perturb_poses = _example.perturb_poses
run_stereo_vo = _example.run_stereo_vo


@pytest.fixture(scope="module")
def vo():
    return load_stereo_vo("_large")  # 26 poses, 8189 stereo measurements of 2634 landmarks


def _poses(values: gtsam.Values, ids) -> np.ndarray:  # -> [P, 4, 4]
    return np.array([values.atPose3(keyframe_key(int(p))).matrix() for p in ids])


def _trans_rmse(A: np.ndarray, B: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((A[:, :3, 3] - B[:, :3, 3]) ** 2, axis=1))))


def _rot_max_deg(A: np.ndarray, B: np.ndarray) -> float:
    return max(
        np.degrees(np.linalg.norm(gtsam.Rot3.Logmap(gtsam.Rot3(a[:3, :3].T @ b[:3, :3]))))
        for a, b in zip(A, B)
    )


def _error(be: Backend, values: gtsam.Values) -> float:
    return sum(be.factor(h).error(values) for h in range(be.num_factors))


def test_stereo_ba_recovers_vo_poses_from_noisy_start(vo):
    T0 = perturb_poses(vo.T_world_cam, rot_sigma=0.02, trans_sigma=0.2, seed=0)
    assert _trans_rmse(T0, vo.T_world_cam) > 0.2  # measured 0.31 m, 3.1 deg
    be, initial = run_stereo_vo(vo, T0)
    T = _poses(be.values(), vo.pose_ids)
    # measured after one iSAM2 update per camera: 2.3 cm RMSE, 0.25 deg max vs the file's VO poses
    assert _trans_rmse(T, vo.T_world_cam) < 0.06
    assert _rot_max_deg(T, vo.T_world_cam) < 0.6
    assert np.allclose(T[0], vo.T_world_cam[0], atol=1e-5)  # the gauge stayed put
    assert be.error() < 0.02 * _error(be, initial)  # measured 2582 vs 3.0e5 (0.0085; Huber, 8189 factors)


def test_stereo_ba_converges_to_the_same_optimum_from_any_start(vo):
    """Batch LM after iSAM2: a large perturbation (0.05 rad, 0.5 m) ends where the clean start does."""
    ends = []
    for rot, trans in ((0.0, 0.0), (0.05, 0.5)):
        be, _ = run_stereo_vo(vo, perturb_poses(vo.T_world_cam, rot, trans, seed=1))
        be.refine_batch()
        ends.append(_poses(be.values(), vo.pose_ids))
    assert _trans_rmse(ends[0], ends[1]) < 3e-5  # measured 1.1e-5 m
    assert _rot_max_deg(ends[0], ends[1]) < 1.5e-4  # measured 5.3e-5 deg
    assert _trans_rmse(ends[1], vo.T_world_cam) < 0.05  # measured 2.1 cm: BA refines the VO poses


def _shared_points(vo, a: int, b: int):
    """Landmarks seen by poses a and b: their stereo points in each camera and a per-point sigma (m)."""
    oa, ob = vo.obs[vo.obs[:, 0] == a], vo.obs[vo.obs[:, 0] == b]
    common, ia, ib = np.intersect1d(oa[:, 1], ob[:, 1], return_indices=True)
    Xa, Xb = oa[ia, 5:8], ob[ib, 5:8]
    fb = vo.calib.fx() * vo.calib.baseline()
    z = np.maximum(Xa[:, 2], Xb[:, 2])
    return Xa, Xb, np.maximum(0.05, z**2 / fb)  # stereo depth std for 1 px disparity noise


def test_our_factor_and_gtsam_factors_share_keys_without_special_cases(vo):
    """Our batched point factor (SING3R adjacency residual, Pose3) between consecutive cameras AND
    gtsam's GenericStereoFactor3D on the same pose keys, in one Backend, incrementally."""
    ids = vo.pose_ids[:10]
    T0 = perturb_poses(vo.T_world_cam[:10], rot_sigma=0.02, trans_sigma=0.2, seed=2)
    X, L = keyframe_key, (lambda j: user_key("l", j))
    cal, noise = vo.calib, gtsam.noiseModel.Isotropic.Sigma(3, 1.0)
    be = Backend()
    initial = gtsam.Values()
    kinds = []
    for k, pid in enumerate(ids):
        pose = gtsam.Pose3(T0[k])
        be.add_value(X(pid), pose)
        initial.insert(X(pid), pose)
        if k == 0:
            be.add_factor(gtsam.PriorFactorPose3(X(pid), pose, gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
        else:
            Xa, Xb, sig = _shared_points(vo, ids[k - 1], pid)
            be.add_factor(make_point_factor(X(ids[k - 1]), X(pid), Xa, Xb, sig, group="pose3"))
            kinds.append("ours")
        if k % 2 == 0:  # every other camera also gets its stereo measurements (gtsam factors)
            for row in vo.obs[vo.obs[:, 0] == pid]:
                lid = int(row[1])
                if not be.has_value(L(lid)):
                    be.add_value(L(lid), pose.transformFrom(row[5:8]))
                    initial.insert(L(lid), pose.transformFrom(row[5:8]))
                be.add_factor(
                    gtsam.GenericStereoFactor3D(gtsam.StereoPoint2(*row[2:5]), noise, X(pid), L(lid), cal)
                )
                kinds.append("gtsam")
        be.update()
    assert kinds.count("ours") == 9 and kinds.count("gtsam") > 1000
    e0 = _error(be, initial)
    be.update(extra_iterations=3)
    T = _poses(be.values(), ids)
    assert be.error() < 0.007 * e0  # measured 514 vs 2.0e5 (0.0026)
    # measured: iSAM2 2.9 cm RMSE, 0.27 deg vs VO poses from a 0.35 m perturbation
    assert _trans_rmse(T, vo.T_world_cam[:10]) < 0.08
    assert _rot_max_deg(T, vo.T_world_cam[:10]) < 0.7

    # no special case: plain gtsam LM on the very same factor objects reaches the same optimum
    graph = gtsam.NonlinearFactorGraph()
    for h in range(be.num_factors):
        graph.add(be.factor(h))
    lm = gtsam.LevenbergMarquardtOptimizer(graph, initial, gtsam.LevenbergMarquardtParams()).optimize()
    be.refine_batch()
    T_lm, T_be = _poses(lm, ids), _poses(be.values(), ids)
    assert _trans_rmse(T_lm, T_be) < 1.5e-6  # measured 4.9e-7 m
    assert abs(graph.error(lm) - be.error()) < 1e-10 * graph.error(lm)  # measured 3.2e-11
