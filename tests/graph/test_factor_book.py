"""The backend's bookkeeping (gsslam/graph/factor_book.py): handles, the buffer, rejections, the log."""

import gtsam
import numpy as np
import pytest

from gsslam.graph.factor_book import FactorBook
from gsslam.graph.rejection import BackendError

NOISE = gtsam.noiseModel.Isotropic.Sigma(6, 0.1)


def _prior(key):
    return gtsam.PriorFactorPose3(key, gtsam.Pose3(), NOISE)


def _between(a, b):
    return gtsam.BetweenFactorPose3(a, b, gtsam.Pose3(), NOISE)


def test_a_factor_naming_a_variable_without_value_and_an_unconstrained_value_are_dropped():
    book = FactorBook()
    book.add_value(1, gtsam.Pose3())
    book.add_value(7, gtsam.Pose3())  # nothing will constrain it
    keep = book.add_factor(_prior(1), "prior x1", spec=("prior",))
    lost = book.add_factor(_between(1, 2), "odometry 1-2", spec=("between",))
    rejected = book.reject_missing_keys()
    assert [r.handle for r in rejected if r.handle is not None] == [lost]
    assert "odometry 1-2" in rejected[0].what and "missing key" in rejected[0].cause
    assert [r.key for r in rejected if r.key is not None] == [7]
    assert book.pending == [keep] and list(book.factors) == [keep]
    assert book.has_value(1) and not book.has_value(7) and list(book.new_values.keys()) == [1]


def test_removal_of_a_buffered_factor_is_immediate_and_of_a_sent_one_waits_for_the_update():
    book = FactorBook()
    book.add_value(1, gtsam.Pose3())
    sent = book.add_factor(_prior(1), None, spec=("prior",))
    book.mark_sent([40])
    assert book.index == {sent: 40} and book.pending == [] and book.new_values.size() == 0
    buffered = book.add_factor(_prior(1), None, spec=("prior",))
    book.remove([buffered, sent])
    assert book.pending == [] and book.to_remove == [sent] and book.factors == {}
    book.mark_sent([])
    assert book.index == {} and book.to_remove == []
    with pytest.raises(BackendError, match="unknown or already removed"):
        book.remove([sent])
    assert [op[0] for op in book.log] == ["value", "factor", "factor", "remove"]


def test_what_is_not_plain_data_makes_the_log_unreplayable_and_the_first_reason_stays():
    book = FactorBook()
    x1 = gtsam.symbol("x", 1)
    book.add_value(x1, np.zeros(3))  # vectors, Pose3 and Similarity3 are plain data
    assert book.unreplayable is None
    book.add_value(2, gtsam.Rot3())
    assert book.unreplayable == "value 2 is a Rot3"
    h = book.add_factor(_prior(x1), "user prior", spec=None)
    assert book.describe(h) == "factor 'user prior' (PriorFactorPose3 on x1)"
    assert book.unreplayable == "value 2 is a Rot3"
