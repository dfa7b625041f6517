"""Loop constraints through the real SubmapGraph (iSAM2): add_loop, update, check_loops, remove."""

from __future__ import annotations

import dataclasses

import numpy as np

from gsslam.config import GraphConfig, LoopConfig
from gsslam.datasets.synthetic import block_room, make_submaps
from gsslam.datasets.synthetic.trajectories import outward_circle
from gsslam.geometry import make_T, so3_exp, so3_log, split_sim3
from gsslam.graph import submap_graph
from gsslam.loop import LoopDetector, propagate_correction
from helpers.loop_scenes import DRIFT, wrong_loop


def _drifted_encodings(sm, rng):
    """Drift enters the chain as a yaw error on each submap's last keyframe pose (the shared one)."""
    out = []
    for s, enc in enumerate(sm.encodings):
        T = enc.T_local_cam.copy()
        if s < len(sm.encodings) - 1:
            w = np.array([0.0, np.radians(DRIFT["drift_yaw_deg"]), 0.0]) + DRIFT[
                "drift_noise"
            ] * rng.standard_normal(3)
            T[-1] = T[-1] @ make_T(so3_exp(w), DRIFT["drift_noise"] * rng.standard_normal(3))
        out.append(dataclasses.replace(enc, T_local_cam=T))
    return out


def test_loops_through_submap_graph():
    sm = make_submaps(block_room(seed=1), outward_circle(61, 1.2), mono=False, seed=0)
    encs = _drifted_encodings(sm, np.random.default_rng(0))
    graph = submap_graph.SubmapGraph(GraphConfig(), monocular=False)
    det = LoopDetector(LoopConfig(), mode="rgbd")
    loops, before = {}, None
    for s, enc in enumerate(encs):
        graph.add_submap(enc)
        graph.update()
        det.add_submap(s, enc, sm.images[s])
        poses = {k: graph.submap_pose(k) for k in range(graph.num_submaps)}
        found = det.detect(s, poses)
        if found and before is None:
            before = poses
        for lc in found:
            loops[graph.add_loop(lc.i, lc.m, lc.X_i, lc.X_m)] = lc
        if found:
            graph.update()
    assert any(lc.i >= 8 and lc.m <= 1 for lc in loops.values())
    after = {k: graph.submap_pose(k) for k in range(graph.num_submaps)}
    assert det.check_loops(loops, after) == []  # the graph satisfies the true loops
    corr = propagate_correction(before, after)
    assert np.degrees(np.linalg.norm(so3_log(split_sim3(corr[8])[0]))) > 3.0  # the loop side moved ...
    assert np.abs(corr[0] - np.eye(4)).max() < 1e-3  # ... the gauge did not

    # a wrong loop forced into the graph is named by check_loops; removing it restores the rest
    bad = wrong_loop(sm, det)
    h_bad = graph.add_loop(bad.i, bad.m, bad.X_i, bad.X_m)
    graph.update()
    poses_bad = {k: graph.submap_pose(k) for k in range(graph.num_submaps)}
    assert det.check_loops({**loops, h_bad: bad}, poses_bad)[0] == h_bad
    graph.remove_factor(h_bad)
    graph.update()
    poses_fixed = {k: graph.submap_pose(k) for k in range(graph.num_submaps)}
    assert det.check_loops(loops, poses_fixed) == []


def _submap_ate(graph, sm) -> float:
    from gsslam.eval.ate import ate_from_pairs

    est = np.array([graph.submap_pose(k)[:3, 3] for k in range(graph.num_submaps)])
    gt = np.array([sm.T_world_local_gt[k][:3, 3] for k in range(graph.num_submaps)])
    return ate_from_pairs(gt, est, "se3").stats.rmse


def test_loop_closure_through_submap_graph_cuts_ate_with_default_weights():
    sm = make_submaps(block_room(seed=1), outward_circle(61, 1.2), mono=False, seed=0)
    encs = _drifted_encodings(sm, np.random.default_rng(0))
    results = {}
    for loops_on in (False, True):
        graph = submap_graph.SubmapGraph(GraphConfig(), monocular=False)
        det = LoopDetector(LoopConfig(enabled=loops_on), mode="rgbd")
        for s, enc in enumerate(encs):
            graph.add_submap(enc)
            graph.update()
            det.add_submap(s, enc, sm.images[s])
            found = det.detect(s, {k: graph.submap_pose(k) for k in range(graph.num_submaps)})
            for lc in found:
                graph.add_loop(lc.i, lc.m, lc.X_i, lc.X_m)
            if found:
                graph.update()
        graph.update(extra_iterations=5)
        results[loops_on] = (_submap_ate(graph, sm), det.stats.to_dict())
    (ate_without, _), (ate_with, stats) = results[False], results[True]
    assert ate_without > 0.05  # the injected drift is visible
    assert ate_with <= ate_without / 3, (ate_without, ate_with, stats)
