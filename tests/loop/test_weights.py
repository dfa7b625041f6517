"""Mono loop weights (gsslam.loop.weights): a loop's per-point sigma is its own inlier residual."""

from __future__ import annotations

import dataclasses

import numpy as np

from gsslam.config import GraphConfig, LoopConfig
from gsslam.geometry import make_T, so3_exp, umeyama
from gsslam.graph.submap_graph import SubmapGraph
from gsslam.loop import LoopConstraint
from gsslam.loop.weights import inlier_rms, loop_point_sigma
from helpers.submap_chain import ate, loop_points, make_chain


def _loop(X_m, noise, rng, T=None, thr=0.1):
    T = make_T(so3_exp(np.array([0.1, -0.2, 0.3])), np.array([0.5, 0.0, -1.0]), 1.3) if T is None else T
    X_i = X_m @ T[:3, :3].T + T[:3, 3] + noise * rng.standard_normal(X_m.shape)
    return LoopConstraint(0, 5, X_i, X_m, umeyama(X_m, X_i, with_scale=True), 0.5, 0.8, thr)


def test_sigma_is_the_inlier_rms():
    rng = np.random.default_rng(0)
    lc = _loop(rng.uniform(-1, 1, (400, 3)) + [0, 0, 3], 0.01, rng, thr=0.04)  # floor 0.01 < rms
    cfg = LoopConfig()
    rms = inlier_rms(lc)
    assert 0.014 < rms < 0.019  # 3-D RMS of 0.01 per axis: ~0.0173 (minus the fit's 7 dof)
    assert np.isclose(loop_point_sigma(lc, "mono", cfg), rms)  # submap-i units
    assert loop_point_sigma(lc, "rgbd", cfg) is None  # RGB-D: graph.loop_sigma_m (metric)
    assert loop_point_sigma(lc, "mono", dataclasses.replace(cfg, mono_sigma_from_residual=False)) is None


def test_sigma_has_a_floor_relative_to_the_inlier_distance():
    rng = np.random.default_rng(1)
    exact = _loop(rng.uniform(-1, 1, (50, 3)) + [0, 0, 3], 0.0, rng, thr=0.08)
    assert inlier_rms(exact) < 1e-9
    sigma = loop_point_sigma(exact, "mono", LoopConfig(mono_sigma_min_rel=0.25))
    assert np.isclose(sigma, 0.25 * 0.08)


def test_mono_loop_weighted_by_its_residual_corrects_scale_drift():
    """A Sim(3) loop factor corrects the scale drift of a mono chain, not only a rigid offset."""
    n = 20
    encs, truth = make_chain(n, drift=0.02, seed=0)  # ~2 % scale drift per submap
    rng = np.random.default_rng(1)
    X_i, X_m = loop_points(encs, n - 1, 6, 0, 0, step=2)  # the last frame revisits frame 0
    X_i = X_i + 0.005 * np.median(X_i[:, 2]) * rng.standard_normal(X_i.shape)  # 0.5 % of depth per axis
    thr = LoopConfig().inlier_threshold_rel * float(np.median(X_i[:, 2]))
    lc = LoopConstraint(n - 1, 0, X_i, X_m, umeyama(X_m, X_i, with_scale=True), 0.6, 0.8, thr)

    g = SubmapGraph(GraphConfig(), monocular=True)
    for e in encs:
        g.add_submap(e)
        g.update()

    def scale_error() -> float:  # log of the last submap's scale against the truth
        return abs(float(np.log(g.submap_scales()[-1] / encs[-1].meta["unit"] * encs[0].meta["unit"])))

    ate_open, scale_open = ate(g.keyframe_poses(), truth), scale_error()
    sigma = loop_point_sigma(lc, "mono", LoopConfig())
    g.add_loop(lc.i, lc.m, lc.X_i, lc.X_m, sigma=sigma, local_units=True)
    g.update(extra_iterations=5)
    # measured: scale error 0.378 -> 0.008 (log), ATE 0.448 -> 0.024 (world units, circle radius 5)
    assert scale_open > 0.3
    assert scale_error() < 0.05
    assert ate(g.keyframe_poses(), truth) < ate_open / 8


def test_loop_stage_adds_mono_loops_with_their_residual_sigma(revisit_mono):
    """The pipeline's loop stage hands each mono loop to the graph with its own sigma."""
    from types import SimpleNamespace

    from gsslam.graph.keys import submap_key
    from gsslam.slam.loop_stage import LoopStage

    sm = revisit_mono[0]
    graph = SubmapGraph(GraphConfig(), monocular=True)
    chain = SimpleNamespace(graph=graph)
    stage = LoopStage(LoopConfig(), "mono")
    for s, (enc, img) in enumerate(zip(sm.encodings, sm.images)):
        graph.add_submap(enc)
        graph.update()
        frames = [SimpleNamespace(index=f, gray=g) for f, g in zip(enc.frame_indices, img)]
        stage.after_submap(chain, 0, s, enc, frames)
    loops = [op[2] for op in graph.backend.replay_log() if op[0] == "factor" and op[2][0] == "relative_point"]
    assert loops, "the revisit closes at least one loop, in submap-i units"
    assert not [op for op in graph.backend.replay_log() if op[0] == "factor" and op[2][0] == "point"
                and op[2][1][0] > op[2][1][1]]  # fmt: skip  # no world-unit loop (add_loop(i, m): i > m)
    for _, (_key_i, _key_m, X_i, X_m, sigma), _ in loops:
        rms = inlier_rms(LoopConstraint(1, 0, X_i, X_m, umeyama(X_m, X_i, with_scale=True), 1.0, 1.0, 1.0))
        assert np.isclose(sigma, rms, rtol=1e-6)  # the floor (0.25 x 2 % of depth) is not active here
