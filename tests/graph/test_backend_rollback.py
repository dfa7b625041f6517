"""The backend cannot be poisoned: a bad factor or value is rolled back, named, and the graph goes on."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from gsslam.graph.backend import Backend, BackendError, RejectedError
from gsslam.graph.keys import keyframe_key as X

NOISE = gtsam.noiseModel.Isotropic.Sigma(6, 0.1)


def _zero_jacobian(this, values, H):
    if H is not None:
        for i in range(len(H)):
            H[i] = np.zeros((6, 6))
    return np.zeros(6)


def _throws(this, values, H):
    raise ValueError("measurement table is empty")


def _between(a, b, t):
    return gtsam.BetweenFactorPose3(X(a), X(b), gtsam.Pose3(gtsam.Rot3(), np.array(t, float)), NOISE)


@pytest.fixture
def chain():
    be = Backend()
    be.add_value(X(0), gtsam.Pose3())
    be.add_factor(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(), NOISE))
    be.add_value(X(1), gtsam.Pose3())
    be.add_factor(_between(0, 1, [1, 0, 0]))
    be.update()
    return be


def test_missing_key_is_named_and_the_rest_applies(chain):
    chain.add_value(X(2), gtsam.Pose3())
    chain.add_factor(_between(1, 2, [1, 0, 0]))
    chain.add_factor(gtsam.PriorFactorPose3(X(23), gtsam.Pose3(), NOISE), name="user prior")
    with pytest.raises(RejectedError, match=r"'user prior' \(PriorFactorPose3 on x23\): missing key x23"):
        chain.update()
    np.testing.assert_allclose(chain.estimate(X(2)).translation(), [2, 0, 0], atol=1e-9)
    assert chain.num_factors == 3  # the prior is gone: later updates and the batch refinement work
    chain.add_value(X(3), gtsam.Pose3())
    chain.add_factor(_between(2, 3, [0, 1, 0]))
    chain.update()
    assert chain.refine_batch() < 1e-12
    np.testing.assert_allclose(chain.estimate(X(3)).translation(), [2, 1, 0], atol=1e-9)


@pytest.mark.parametrize(
    "fn, cause",
    [(_zero_jacobian, "Indeterminate linear system .* near variable x2"), (_throws, "ValueError")],
)
def test_factor_that_breaks_isam2_is_rolled_back(chain, fn, cause):
    chain.add_value(X(2), gtsam.Pose3())
    chain.add_factor(gtsam.CustomFactor(NOISE, [X(1), X(2)], fn), name="bad")
    chain.add_value(X(3), gtsam.Pose3())
    chain.add_factor(_between(1, 3, [0, 1, 0]), name="good")
    with pytest.raises(RejectedError, match=f"factor 'bad' \\(CustomFactor on x1,x2\\): {cause}") as info:
        chain.update()
    assert "'good'" not in str(info.value)
    if fn is _zero_jacobian:  # x2 was only held by the bad factor: it goes too
        assert not chain.has_value(X(2))
    np.testing.assert_allclose(chain.estimate(X(3)).translation(), [1, 1, 0], atol=1e-9)
    chain.add_value(X(4), gtsam.Pose3())
    chain.add_factor(_between(3, 4, [0, 1, 0]))
    chain.update()  # usable: no exception
    np.testing.assert_allclose(chain.estimate(X(4)).translation(), [1, 2, 0], atol=1e-9)


def test_a_batch_without_single_culprit_rolls_back_whole(chain):
    before = chain.num_factors
    chain.add_value(X(2), gtsam.Pose3())
    chain.add_factor(gtsam.CustomFactor(NOISE, [X(1), X(2)], _zero_jacobian))
    chain.add_factor(gtsam.CustomFactor(NOISE, [X(1), X(2)], _zero_jacobian))
    with pytest.raises(RejectedError, match=r"whole update \(2 factors, new values x2\): Indeterminate"):
        chain.update()
    assert chain.num_factors == before and not chain.has_value(X(2))
    np.testing.assert_allclose(chain.estimate(X(1)).translation(), [1, 0, 0], atol=1e-9)


def test_add_factor_rejects_non_factors():
    with pytest.raises(BackendError, match="needs a gtsam factor"):
        Backend().add_factor("not a factor")
