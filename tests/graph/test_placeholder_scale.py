"""A mono scale link across a turn that the encoder guessed (``graph.mono_placeholder_scale_sigma``).

A low-parallax turn hands on a placeholder plane as the shared frame's depth; the next window with
parallax takes its scale from it, a guess (docs/results.md, "Mono across turns, session 13"). Here a
20-submap loop (tests/helpers/submap_chain.py) gets such a guess at submap 8: every later submap is in
units 1 / 0.6 too large while the shared frame (a placeholder, confidence 0) keeps the previous units,
so the scale factor reads the guess as a measurement. The loop at the end must be able to set it.
"""

from __future__ import annotations

import numpy as np

from gsslam.config import GraphConfig
from gsslam.graph.submap_graph import SubmapGraph
from gsslam.types import SubmapEncoding
from helpers.submap_chain import ate, loop_points, make_chain

N, TURN, GUESS = 20, 8, 0.6


def _guessed_chain():
    encs, truth = make_chain(N, drift=0.0, seed=4)
    out = []
    for i, e in enumerate(encs):
        T, P, C, meta = e.T_local_cam.copy(), e.points_cam.copy(), e.confidence.copy(), dict(e.meta)
        if i >= TURN:
            T[:, :3, 3] /= GUESS
            P /= GUESS
        if i == TURN:
            P[0] = encs[TURN - 1].points_cam[-1]  # the placeholder handed on, in the previous units
            C[0] = 0.0
            meta["shared_placeholder"] = True
        if i == TURN - 1:
            C[-1] = 0.0
        out.append(SubmapEncoding(e.frame_indices, T, P, C, e.intrinsics, meta))
    return out, truth


def _closed(encs, sigma: float) -> float:
    g = SubmapGraph(GraphConfig(mono_placeholder_scale_sigma=sigma), monocular=True)
    for e in encs:
        g.add_submap(e)
        g.update()
    g.add_loop(N - 1, 0, *loop_points(encs, N - 1, 6, 0, 0, step=1), local_units=True)
    g.update(extra_iterations=3)
    return ate(g.keyframe_poses(), truth=_TRUTH)


_ENCS, _TRUTH = _guessed_chain()


def test_a_loop_sets_the_scale_that_a_turn_guessed():
    firm = _closed(_ENCS, 0.0)  # the guess held as a measurement (scale_sigma 0.05)
    loose = _closed(_ENCS, 0.5)
    assert firm > 0.15, firm  # measured 0.26 (radius 5): the loop cannot undo the guess
    assert loose < 0.03, loose  # measured 0.007
    assert np.isfinite(loose)
