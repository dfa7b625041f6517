"""A mono window whose shared depth was rendered from the chain's earlier depths (a turn had exhausted
the carried one; ``encoder.mono_world_depth``, gsslam/slam/world_depth.py) keeps the previous submap's
units: its scale link reads 1, not the previous submap's placeholder plane against the rendered depth.

A 20-submap chain (tests/helpers/submap_chain.py); at submap 8 the previous submap's depth of the shared
frame is a placeholder plane at 0.6 x the true median depth (confidence 0), and submap 8 is in the
previous submap's units, its frame 0 the true geometry, as the encoder makes it from the rendered depth.
"""

from __future__ import annotations

import numpy as np

from gsslam.config import GraphConfig
from gsslam.geometry import depth_to_points
from gsslam.graph.submap_graph import SubmapGraph
from gsslam.types import SubmapEncoding
from helpers.submap_chain import ate, make_chain

N, TURN, PLANE = 20, 8, 0.6


def _chain(world_depth: bool):
    encs, truth = make_chain(N, drift=0.0, seed=4)
    # the rendered depth is in the previous submap's units: submap 8 as a whole is put in them
    r = float(np.nanmedian(encs[TURN - 1].points_cam[-1, ..., 2] / encs[TURN].points_cam[0, ..., 2]))
    out = []
    for i, e in enumerate(encs):
        T, P, C, meta = e.T_local_cam.copy(), e.points_cam.copy(), e.confidence.copy(), dict(e.meta)
        if i == TURN:
            T[:, :3, 3] *= r
            P *= r
        if i == TURN - 1:  # the turn left a placeholder plane as the shared frame's depth
            z = PLANE * float(np.nanmedian(P[-1, ..., 2]))
            P[-1] = depth_to_points(e.intrinsics.K, np.full(P.shape[1:3], z, np.float32))
            C[-1] = 0.0
        if i == TURN and world_depth:
            meta["world_depth"] = True
        out.append(SubmapEncoding(e.frame_indices, T, P, C, e.intrinsics, meta))
    return out, truth


def _ate(world_depth: bool) -> float:
    encs, truth = _chain(world_depth)
    g = SubmapGraph(GraphConfig(), monocular=True)
    for e in encs:
        g.add_submap(e)
        g.update()
    return ate(g.keyframe_poses(), truth=truth)


def test_a_rendered_shared_depth_keeps_the_previous_units():
    guessed = _ate(world_depth=False)  # the plane read as a measurement: the scale jumps at submap 8
    rendered = _ate(world_depth=True)
    assert guessed > 0.5, guessed  # measured 1.35 (radius 5)
    assert rendered < 0.02, rendered  # measured 0.0096
