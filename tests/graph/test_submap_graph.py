"""SubmapGraph on a synthetic 50-submap loop with known truth and injected scale drift."""

from __future__ import annotations

import numpy as np
import pytest

from gsslam.config import GraphConfig
from gsslam.graph.keys import submap_key
from gsslam.graph.submap_graph import GraphError, SubmapGraph
from gsslam.types import Correspondences
from helpers.submap_chain import INTR, ate, loop_points, make_chain, true_pose

# The synthetic encoder drifts ~2 % in scale per submap: its shared-frame points are trusted to
# 0.1 world units (50 per pair), a verified loop to 0.02.
CFG = GraphConfig()
N_SUB = 50


@pytest.fixture(scope="module")
def chain():
    return make_chain(N_SUB, drift=0.02, seed=0)


def _positions(g: SubmapGraph) -> np.ndarray:
    return np.array([T[:3, 3] for _, T in sorted(g.keyframe_poses().items())])


def _build(encs) -> SubmapGraph:
    g = SubmapGraph(CFG, monocular=True)
    for e in encs:
        g.add_submap(e)
        g.update()
    return g


def test_loop_closure_fixes_drift_and_isam_matches_batch(chain):
    encs, truth = chain
    g = _build(encs)
    ate_open = ate(g.keyframe_poses(), truth)
    assert abs(np.log(g.submap_scales()[-1] / encs[-1].meta["unit"] * encs[0].meta["unit"])) > 0.5  # drifted
    g.add_loop(N_SUB - 1, 0, *loop_points(encs, N_SUB - 1, 6, 0, 0, step=1))
    g.update(extra_iterations=3)
    ate_loop = ate(g.keyframe_poses(), truth)
    assert ate_open / ate_loop >= 5.0, (ate_open, ate_loop)
    incremental = _positions(g)
    g.refine_batch()
    batch = _positions(g)
    assert np.abs(incremental - batch).max() < 0.02 * 5.0  # 2 % of the circle's radius
    assert ate(g.keyframe_poses(), truth) <= ate_loop * 1.05


def test_wrong_loop_removed_restores_solution(chain):
    encs, truth = chain
    g = _build(encs)
    g.add_loop(N_SUB - 1, 0, *loop_points(encs, N_SUB - 1, 6, 0, 0, step=1))
    g.update(extra_iterations=3)
    good, good_ate = _positions(g), ate(g.keyframe_poses(), truth)
    wrong = g.add_loop(25, 0, *loop_points(encs, 25, 0, 0, 0, step=2))  # half a circle away
    g.update(extra_iterations=3)
    assert ate(g.keyframe_poses(), truth) > 5 * good_ate
    g.remove_factor(wrong)
    g.update(extra_iterations=10)  # iSAM2 takes plain Gauss-Newton steps back from the distorted state
    assert np.abs(_positions(g) - good).max() < 0.05
    with pytest.raises(Exception, match="handle"):
        g.remove_factor(wrong)


def test_rgbd_keeps_metric_scale():
    encs, truth = make_chain(8, drift=0.0, seed=1)
    for e in encs:  # metric point maps: unit 1
        u = e.meta["unit"]
        e.points_cam[:] *= u
        e.T_local_cam[:, :3, 3] *= u
    g = SubmapGraph(GraphConfig(), monocular=False)
    for e in encs:
        g.add_submap(e)
    g.update()
    np.testing.assert_allclose(g.submap_scales(), 1.0, atol=1e-3)
    poses = g.keyframe_poses()
    T0 = truth[0]
    for f in (10, 30, 48):
        np.testing.assert_allclose(np.linalg.inv(T0) @ truth[f], poses[f], atol=0.05)


def _true_values(g: SubmapGraph, encs):
    import gtsam

    from gsslam.factors import to_gtsam

    v = gtsam.Values()
    T0_inv = np.linalg.inv(true_pose(0, len(encs) * 6))
    for i, e in enumerate(encs):
        T = T0_inv @ true_pose(e.frame_indices[0], len(encs) * 6)
        v.insert(submap_key(i), to_gtsam(T @ np.diag([e.meta["unit"]] * 3 + [1.0]), "sim3"))
    return v


def _true_flow_5_to_7(encs, truth):  # -> (uv [192, 2], uv_t [192, 2], source depth [192], target depth [192])
    """Submap 0's frame 5 pixels and their true positions in frame 7 (submap 1), from the ground truth."""
    world = lambda f: np.linalg.inv(truth[0]) @ truth[f]  # noqa: E731  (gauge: first camera)
    uv = np.stack(np.meshgrid(np.arange(16.0), np.arange(12.0)), -1).reshape(-1, 2)
    enc = encs[0]
    X = enc.points_cam[5].reshape(-1, 3)
    Xw = X * enc.meta["unit"] @ world(5)[:3, :3].T + world(5)[:3, 3]
    Tb = np.linalg.inv(world(7))
    Xb = Xw @ Tb[:3, :3].T + Tb[:3, 3]
    return uv, Xb[:, :2] / Xb[:, 2:] * 20.0 + [7.5, 5.5], X[:, 2], Xb[:, 2]


def test_flow_and_depth_prior_are_consistent_with_truth():
    import gtsam

    encs, truth = make_chain(8, drift=0.0, rot_noise_deg=0.0, seed=2)
    g = SubmapGraph(GraphConfig(flow_effective_points=0.0), monocular=True)  # per-match information
    for e in encs:
        g.add_submap(e)
    n = 24
    # source frame 5 (submap 0), target frame 7 (submap 1): project submap 0's points with the truth
    uv, uv_t, z5, z7 = _true_flow_5_to_7(encs, truth)
    assert (z7 > 0).all()
    corr = Correspondences(5, 7, uv, uv_t, z5, np.ones(len(uv)))
    h = g.add_flow(corr, INTR.K)
    assert h is not None
    assert g.add_flow(Correspondences(1, 3, uv, uv, z5, np.ones(len(uv))), INTR.K) is None  # same submap
    with pytest.raises(GraphError, match="not a keyframe"):
        g.add_flow(Correspondences(5, 99, uv, uv_t, z5, np.ones(len(uv))), INTR.K)
    z9 = encs[1].points_cam[3].reshape(-1, 3)[:n, 2] * encs[1].meta["unit"]  # true world depth of frame 9
    hd = g.add_depth_prior(9, uv[:n], z9, INTR.K)  # frame 9 = position 3 of submap 1
    assert hd is not None
    truth_values = _true_values(g, encs)
    assert g.backend.factor(h).error(truth_values) < 1e-12
    moved = gtsam.Values(truth_values)
    moved.update(
        submap_key(1), truth_values.atSimilarity3(submap_key(1)).retract(np.r_[0.0, 0.01, 0, 0, 0, 0, 0])
    )
    assert g.backend.factor(h).error(moved) > 1.0  # 0.01 rad is ~0.2 px at f = 20 px, ~ 1 sigma
    assert g.backend.factor(hd).error(truth_values) < 1e-12
    wrong = g.add_depth_prior(9, uv[:n], 1.2 * z9, INTR.K)
    assert g.backend.factor(wrong).error(truth_values) > 1.0


def test_bad_submaps_are_rejected():
    encs, _ = make_chain(3, seed=3)
    g = SubmapGraph(GraphConfig(), monocular=True)
    g.add_submap(encs[0])
    with pytest.raises(GraphError, match="share"):
        g.add_submap(encs[2])
    with pytest.raises(GraphError, match="only 1 submaps"):
        g.add_loop(0, 5, np.ones((5, 3)), np.ones((5, 3)))


def test_flow_effective_points_scales_the_factor_information():
    import dataclasses

    import gtsam

    encs, truth = make_chain(4, drift=0.0, rot_noise_deg=0.0, seed=2)
    uv, uv_t, z5, _ = _true_flow_5_to_7(encs, truth)
    corr = Correspondences(5, 7, uv, uv_t, z5, np.ones(len(uv)))
    errors = []
    for n_eff in (0.0, 4.0):
        g = SubmapGraph(dataclasses.replace(CFG, flow_effective_points=n_eff), monocular=True)
        for e in encs:
            g.add_submap(e)
        h = g.add_flow(corr, INTR.K)
        v = gtsam.Values(g.backend.values())
        v.update(submap_key(1), v.atSimilarity3(submap_key(1)).retract(np.r_[0.0, 0.01, 0, 0, 0, 0, 0]))
        errors.append(g.backend.factor(h).error(v))
    # 192 matches weigh as 4: the whitened error (and the information) shrinks by 4 / 192
    assert errors[0] > 0 and np.isclose(errors[1] / errors[0], 4 / len(uv), rtol=1e-6)


def test_relative_registration_on_a_revisit_closes_the_loop(chain):
    """The last keyframe (frame 300 = frame 0) registered against the map of submap 0, the owner, as
    a relative pose (the camera at the owner's origin, 1 mm / 1 mrad): it closes the drifted circle
    through the owner's variable rather than the chain frame (measured 4.1x; a single pose does not
    fix the last submap's scale as the loop points of the first test do, >= 5x there)."""
    encs, truth = chain
    g = _build(encs)
    ate_open = ate(g.keyframe_poses(), truth)
    info = np.diag([1e6] * 3 + [1e6 / encs[0].meta["unit"] ** -2] * 3)[None]  # owner units: 1 mm in the world
    g.add_relative_registration(0, N_SUB - 1, [6], np.eye(4)[None], info)
    g.update(extra_iterations=5)
    ate_reg = ate(g.keyframe_poses(), truth)
    assert ate_open / ate_reg >= 3.5, (ate_open, ate_reg)
    with pytest.raises(GraphError, match="submap 50"):
        g.add_relative_registration(0, N_SUB, [6], np.eye(4)[None], info)
