"""Per-character relinearisation thresholds: iSAM2 never sees a threshold of the wrong size."""

from __future__ import annotations

import dataclasses

import gtsam
import numpy as np
import pytest

from gsslam.config import GraphConfig
from gsslam.graph.backend import Backend, BackendError
from gsslam.graph.keys import keyframe_key as X
from gsslam.graph.keys import user_key
from gsslam.graph.noise import isam_params
from gsslam.graph.relinearization import RelinearizeThresholds

NOISE6 = gtsam.noiseModel.Isotropic.Sigma(6, 0.1)
NOISE3 = gtsam.noiseModel.Isotropic.Sigma(3, 0.1)


def _chain(be: Backend, n: int, rng) -> None:
    """Poses 1 m apart along x, initial values off by ~5 cm / 3 deg; one update per pose."""
    for k in range(n):
        truth = gtsam.Pose3(gtsam.Rot3(), np.array([k, 0.0, 0.0]))
        be.add_value(X(k), truth.retract(rng.normal(scale=0.05, size=6)))
        if k == 0:
            be.add_factor(gtsam.PriorFactorPose3(X(0), truth, NOISE6))
        else:
            rel = gtsam.Pose3(gtsam.Rot3(), np.array([1.0, 0, 0]))
            be.add_factor(gtsam.BetweenFactorPose3(X(k - 1), X(k), rel, NOISE6))
        be.update()


def _backend(overrides) -> Backend:
    cfg = GraphConfig()
    return Backend(isam_params(cfg), thresholds=RelinearizeThresholds(cfg.relinearize_threshold, overrides))


def test_a_wrong_sized_threshold_is_refused_naming_the_key():
    be = _backend({"w": [0.1] * 6})  # a plugin's character, given a 6-entry threshold
    with pytest.raises(BackendError, match=r"variable w3 \(Vector, dimension 3\).*'w' has 6 entries"):
        be.add_value(user_key("w", 3), np.zeros(3))
    assert not be.has_value(user_key("w", 3))  # nothing was buffered
    # the characters gsslam declares are checked at once: velocities are 3-dim, biases 6-dim
    with pytest.raises(BackendError, match=r"'v' has 6 entries; 'v' variables have dimension 3"):
        RelinearizeThresholds(0.01, {"v": [0.1] * 6})
    with pytest.raises(BackendError, match=r"'b' has 3 entries; 'b' variables have dimension 6"):
        RelinearizeThresholds(0.01, {"b": [0.1, 0.1, 0.1]})


def test_one_character_holds_one_dimension():
    be = _backend({"v": 0.1})
    be.add_value(user_key("v", 0), np.zeros(3))
    with pytest.raises(BackendError, match=r"variable v1 \(Vector, dimension 6\).*dimension 3"):
        be.add_value(user_key("v", 1), np.zeros(6))
    # a plugin's character: the first variable fixes its dimension
    be.add_value(user_key("l", 0), gtsam.Point3(0, 0, 0))
    with pytest.raises(BackendError, match=r"variable l1 \(Pose3, dimension 6\)"):
        be.add_value(user_key("l", 1), gtsam.Pose3())


def test_a_new_character_grows_the_map_and_the_estimate_is_kept():
    typed, scalar = _backend({"v": 0.1, "b": 0.1}), Backend(isam_params(GraphConfig()))
    for be in (typed, scalar):
        _chain(be, 6, np.random.default_rng(3))
    # a plugin adds landmarks under a character the map lacks: iSAM2 is rebuilt with it, once
    for be in (typed, scalar):
        for i in range(3):
            be.add_value(user_key("l", i), gtsam.Point3(i, 1.0, 0.0))
            be.add_factor(gtsam.PriorFactorPoint3(user_key("l", i), gtsam.Point3(i, 1.0, 0.0), NOISE3))
        be.update(extra_iterations=3)
    for k in range(6):
        np.testing.assert_allclose(typed.estimate(X(k)).translation(), [k, 0, 0], atol=1e-6)
        # same optimum as the scalar threshold (0.01 everywhere = the map's entries for x and l)
        np.testing.assert_allclose(typed.estimate(X(k)).matrix(), scalar.estimate(X(k)).matrix(), atol=1e-7)
    np.testing.assert_allclose(typed.estimate(user_key("l", 2)), [2, 1, 0], atol=1e-9)
    assert typed.num_factors == scalar.num_factors == 9


def test_without_overrides_the_scalar_threshold_is_used_and_nothing_checked():
    th = RelinearizeThresholds.from_config(
        dataclasses.replace(
            GraphConfig(), relinearize_threshold_velocity=0.0, relinearize_threshold_bias=0.01
        )
    )
    assert not th.typed  # 0 and "= relinearize_threshold" both mean: the scalar threshold
    assert th.admit(user_key("v", 0), 7) is False
    th = RelinearizeThresholds.from_config(GraphConfig())
    assert th.typed and th.vector("v").tolist() == [0.1] * 3 and th.vector("x").tolist() == [0.01] * 6
    assert th.vector("s").shape == (7,) and th.vector("b").shape == (6,)


@pytest.mark.slow  # two 30-keyframe bench graphs with IMU (~40 s on 2 shared cores)
def test_bench_graph_accuracy_unchanged_with_typed_thresholds():
    from gsslam.bench.graph import run_one

    scalar_cfg = dataclasses.replace(
        GraphConfig(), relinearize_threshold_velocity=0.0, relinearize_threshold_bias=0.0
    )
    typed = run_one(30, 60, GraphConfig(), imu=True)  # default: v and b at 0.1
    scalar = run_one(30, 60, scalar_cfg, imu=True)
    assert typed["factors"] == scalar["factors"]
    # measured at 30 keyframes / 60 points: max error 0.0500 m both; relinearised 13.0 vs 24.7 per update
    assert abs(typed["isam2_position_error_max_m"] - scalar["isam2_position_error_max_m"]) < 0.005
    assert typed["isam2_relinearized_mean"] < scalar["isam2_relinearized_mean"]
