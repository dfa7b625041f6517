"""The backend's replay log (checkpoints): replaying a graph's changes into a fresh backend rebuilds
the identical iSAM2 state, including removals, a loop and a batch refinement."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from gsslam.config import GraphConfig
from gsslam.graph.backend import Backend, BackendError
from gsslam.graph.factor_specs import FactorSpecError, build_factor, spec
from gsslam.graph.submap_graph import SubmapGraph
from helpers.submap_chain import loop_points, make_chain

CFG = GraphConfig()


def _replayed(g: SubmapGraph) -> Backend:
    b = Backend.from_config(g.backend.config)
    b.replay(g.backend.replay_log(), build_factor)
    return b


def _values(b: Backend, n: int) -> np.ndarray:  # [n, 4, 4]
    vals = b.values()
    return np.array([vals.atSimilarity3(gtsam.symbol("s", i)).matrix() for i in range(n)])


def test_replay_rebuilds_the_identical_graph():
    encs, _ = make_chain(12, drift=0.02, seed=3)
    g = SubmapGraph(CFG, monocular=True)
    for e in encs:
        g.add_submap(e)
        g.update()
    loop = g.add_loop(11, 0, *loop_points(encs, 11, 6, 0, 0, step=1))
    g.update(extra_iterations=2)
    wrong = g.add_loop(6, 0, *loop_points(encs, 6, 0, 0, 0, step=2))
    g.update()
    g.remove_factor(wrong)
    g.update(extra_iterations=2)
    b = _replayed(g)
    assert b.num_factors == g.backend.num_factors and b.factor_index(loop) == g.backend.factor_index(loop)
    np.testing.assert_array_equal(_values(b, 12), _values(g.backend, 12))  # measured: identical
    # both go on the same way: a batch refinement after the replay
    g.refine_batch()
    b.refine_batch()
    np.testing.assert_array_equal(_values(b, 12), _values(g.backend, 12))


def test_a_factor_without_spec_makes_the_log_unreplayable():
    encs, _ = make_chain(3, drift=0.0, seed=1)
    g = SubmapGraph(CFG, monocular=True)
    g.add_submap(encs[0])
    g.update()
    g.backend.replay_log()  # fine so far
    noise = gtsam.noiseModel.Isotropic.Sigma(7, 0.1)
    g.backend.add_factor(
        gtsam.PriorFactorSimilarity3(gtsam.symbol("s", 0), gtsam.Similarity3(), noise), "mine"
    )
    with pytest.raises(BackendError, match="without a spec"):
        g.backend.replay_log()


def test_specs_name_only_known_makers():
    with pytest.raises(FactorSpecError, match="unknown factor kind"):
        build_factor(("system", ("ls",), {}))
    with pytest.raises(FactorSpecError, match="unknown factor kind"):
        spec("eval")
