"""The per-submap translation stretch (graph.mono_translation_stretch) on a synthetic chain with known truth:
one submap's local translations are 10 % long (its point maps are right); cross-submap flow factors,
projected with the true poses, let its stretch variable find the 10 %."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from gsslam.config import GraphConfig
from gsslam.graph.submap_graph import SubmapGraph
from gsslam.types import Correspondences
from helpers.submap_chain import INTR, ate, make_chain

N_SUB, K, BAD, STRETCH = 8, 6, 3, 1.1


def _stretched_chain():
    encs, truth = make_chain(N_SUB, K=K, drift=0.0, rot_noise_deg=0.0, seed=3)
    encs[BAD].T_local_cam[:, :3, 3] *= STRETCH  # translations long, depth right
    return encs, truth


def _true_flow(encs, truth, src: int, tgt: int) -> Correspondences:
    """Every pixel of keyframe ``src`` (in its owning submap's units) and where it truly lands in ``tgt``."""
    enc = encs[src // K]  # (src is never a shared frame here)
    X = enc.points_cam[src % K].reshape(-1, 3)
    T_src, T_tgt = truth[src], truth[tgt]
    Xw = (X * enc.meta["unit"]) @ T_src[:3, :3].T + T_src[:3, 3]
    Tb = np.linalg.inv(T_tgt)
    Xb = Xw @ Tb[:3, :3].T + Tb[:3, 3]
    uv = np.stack(np.meshgrid(np.arange(16.0), np.arange(12.0)), -1).reshape(-1, 2)
    uv_t = Xb[:, :2] / Xb[:, 2:] * INTR.fx + [INTR.cx, INTR.cy]
    return Correspondences(src, tgt, uv, uv_t, X[:, 2], np.ones(len(uv)))


def _solve(encs, truth, stretch: bool) -> SubmapGraph:
    g = SubmapGraph(dataclasses.replace(GraphConfig(), mono_translation_stretch=stretch), monocular=True)
    for i, e in enumerate(encs):
        g.add_submap(e)
        if i > 0:  # the last keyframes of submap i-1 into the first ones of submap i
            for src in range(K * i - 3, K * i):
                for tgt in range(K * i + 1, K * i + 4):
                    g.add_flow(_true_flow(encs, truth, src, tgt), INTR.K)
        g.update()
    g.refine_batch()
    return g


@pytest.fixture(scope="module")
def solved():
    encs, truth = _stretched_chain()
    return _solve(encs, truth, False), _solve(encs, truth, True), truth


def test_stretch_recovers_a_long_submap(solved):
    _, g, _ = solved
    t = g.submap_stretches()
    assert abs(t[BAD] + np.log(STRETCH)) < 0.002, t  # measured: -0.0953 (log 1/1.1 = -0.0953)
    others = np.delete(t, BAD)
    assert np.abs(others).max() < 0.002, t  # measured: < 5e-5


def test_stretch_lowers_keyframe_ate(solved):
    off, on, truth = solved
    T0 = np.linalg.inv(truth[0])
    gt = {f: T0 @ T for f, T in truth.items()}
    a_off, a_on = ate(off.keyframe_poses(), gt), ate(on.keyframe_poses(), gt)
    assert a_on < 0.01 * a_off, (a_off, a_on)  # measured: 0.19 -> 0.0001


def test_rgbd_graph_has_no_stretch():
    encs, _ = make_chain(3, drift=0.0, seed=4)
    cfg = dataclasses.replace(GraphConfig(), mono_translation_stretch=True)
    g = SubmapGraph(cfg, monocular=False)
    plain = SubmapGraph(GraphConfig(), monocular=False)
    for e in encs:
        g.add_submap(e)
        plain.add_submap(e)
    g.update()
    plain.update()
    assert not g.stretch and np.all(g.submap_stretches() == 0)
    assert len(g.backend.replay_log()) == len(plain.backend.replay_log())
    for f, T in plain.keyframe_poses().items():
        assert np.array_equal(g.keyframe_poses()[f], T)


def test_mono_ray_loop_with_views_uses_both_stretches():
    """A ray-point loop that names its points' keyframes goes on both submaps' stretches; one whose
    keyframes are unknown stays on the submaps alone."""
    encs, truth = _stretched_chain()
    g = _solve(encs, truth, True)
    j = K  # the shared frame: frame K of submap BAD, frame 0 of submap BAD + 1
    L = encs[BAD].T_local_cam[j]
    X_i = encs[BAD].points_cam[j].reshape(-1, 3) @ L[:3, :3].T + L[:3, 3]
    X_m = encs[BAD + 1].points_cam[0].reshape(-1, 3)
    views = (np.full(len(X_i), j), np.zeros(len(X_i), dtype=int))
    h = g.add_loop(BAD, BAD + 1, X_i, X_m, 0.05, local_units=True, sigma_perp=0.01, views=views)
    h0 = g.add_loop(BAD, BAD + 1, X_i, X_m, 0.05, local_units=True, sigma_perp=0.01)
    assert g.backend.live_specs()[-2][0] == "stretched_ray_point"
    assert g.backend.live_specs()[-1][0] == "ray_point"
    vals = g.backend.values()  # the solution found from flow (before these loops)
    assert g.backend.factor(h).error(vals) < 1e-3  # the stretched points agree there (measured 6e-4)
    assert g.backend.factor(h0).error(vals) > 5000.0  # the unstretched ones do not (measured 16243)
