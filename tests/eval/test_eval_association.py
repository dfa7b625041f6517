"""Timestamp association: nearest neighbour within max_dt, one-to-one, typed errors."""

from __future__ import annotations

import numpy as np
import pytest

from gsslam.eval.association import AssociationError, associate
from gsslam.types import Trajectory


def _traj(stamps) -> Trajectory:
    return Trajectory(np.asarray(stamps, dtype=float), np.tile(np.eye(4), (len(stamps), 1, 1)))


def test_nearest_within_window_and_order():
    gt = _traj([0.0, 0.1, 0.2, 0.3, 0.4])
    est = _traj([0.095, 0.31, 0.5, -0.2])  # 0.5 and -0.2 have no partner within 0.02 s
    a = associate(gt, est, max_dt=0.02)
    assert a.gt_indices.tolist() == [1, 3]
    assert a.est_indices.tolist() == [0, 1]
    np.testing.assert_allclose(a.dt, [0.005, 0.01])


def test_tie_picks_earlier_and_pairs_are_one_to_one():
    gt = _traj([0.0, 0.02, 1.0])
    est = _traj([0.01, 0.011, 0.012, 5.0])  # est is longer: every gt stamp looks for its nearest est
    a = associate(gt, est, max_dt=0.015)
    assert list(zip(a.gt_indices.tolist(), a.est_indices.tolist())) == [(0, 0), (1, 2)]
    # gt longer than est: est stamps 0.092 and 0.105 both pick gt 0.1; only the closer keeps it
    gt2 = _traj([0.0, 0.1, 0.2, 0.3])
    est2 = _traj([0.092, 0.105, 0.299])
    b = associate(gt2, est2, max_dt=0.02)
    assert list(zip(b.gt_indices.tolist(), b.est_indices.tolist())) == [(1, 1), (3, 2)]
    np.testing.assert_allclose(b.dt, [0.005, 0.001])


def test_unsorted_input_is_handled():
    gt = _traj([0.3, 0.1, 0.2, 0.0])
    est = _traj([0.0, 0.1, 0.2, 0.3, 0.4])
    a = associate(gt, est)
    assert a.gt_indices.tolist() == [0, 1, 2, 3]  # in the order of the shorter trajectory (gt)
    assert a.est_indices.tolist() == [3, 1, 2, 0]


def test_no_pairs_is_an_error():
    with pytest.raises(AssociationError, match="max_dt=0.02"):
        associate(_traj([0.0, 1.0]), _traj([10.0, 11.0]))
    with pytest.raises(AssociationError, match="max_dt must be"):
        associate(_traj([0.0]), _traj([0.0]), max_dt=-1)


def test_inputs_not_modified():
    gt = _traj([0.0, 0.1, 0.2])
    est = _traj([0.2, 0.0, 0.1])
    g0, e0 = gt.timestamps.copy(), est.timestamps.copy()
    associate(gt, est)
    np.testing.assert_array_equal(gt.timestamps, g0)
    np.testing.assert_array_equal(est.timestamps, e0)
