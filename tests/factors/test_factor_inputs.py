"""Bad measurements fail at construction with FactorInputError, never as a silent bad factor."""

from __future__ import annotations

import numpy as np
import pytest
from gtsam.symbol_shorthand import S

from gsslam.factors import (
    FactorInputError,
    make_depth_prior_factor,
    make_flow_factor,
    make_point_factor,
    make_scale_factor,
    make_submap_alignment_factor,
)

K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])


def _flow(**kw):
    rng = np.random.default_rng(0)
    args = dict(
        uv_src=rng.uniform(0, 400, (10, 2)),
        depth_src=rng.uniform(1, 3, 10),
        uv_tgt=rng.uniform(0, 400, (10, 2)),
        K=K,
    )
    args.update(kw)
    return make_flow_factor(S(0), S(1), **args)


def test_flow_rejects_bad_input():
    uv = np.ones((10, 2))
    with pytest.raises(FactorInputError, match="NaN"):
        _flow(uv_src=np.where(np.arange(20).reshape(10, 2) == 3, np.nan, uv))
    with pytest.raises(FactorInputError, match="NaN"):
        _flow(depth_src=np.r_[np.inf, np.ones(9)])
    with pytest.raises(FactorInputError, match="at least 3"):
        _flow(uv_src=uv[:2], uv_tgt=uv[:2], depth_src=np.ones(2))
    with pytest.raises(FactorInputError, match="uv_tgt"):
        _flow(uv_tgt=uv[:9])
    with pytest.raises(FactorInputError, match="positive"):
        _flow(depth_src=-np.ones(10))
    with pytest.raises(FactorInputError, match="group"):
        _flow(group="se2")
    with pytest.raises(FactorInputError, match="two different"):
        make_flow_factor(S(0), S(0), uv, np.ones(10), uv, K)
    assert isinstance(FactorInputError("x"), ValueError)


def test_points_scale_alignment_depth_reject_bad_input():
    X = np.ones((5, 3))
    with pytest.raises(FactorInputError, match="same shape"):
        make_point_factor(S(0), S(1), X, X[:4], 0.1)
    with pytest.raises(FactorInputError, match="at least 3"):
        make_point_factor(S(0), S(1), X[:2], X[:2], 0.1)
    with pytest.raises(FactorInputError, match="NaN"):
        make_point_factor(S(0), S(1), np.full((5, 3), np.nan), X, 0.1)
    with pytest.raises(FactorInputError, match="sigma"):
        make_point_factor(S(0), S(1), X, X, 0.0)
    with pytest.raises(FactorInputError, match="finite"):
        make_scale_factor(S(0), S(1), np.nan, 0.1)
    with pytest.raises(FactorInputError, match="rigid"):
        make_submap_alignment_factor(S(0), S(1), np.diag([2.0, 2, 2, 1]), 0.1, 0.1)
    with pytest.raises(FactorInputError, match="positive"):
        make_depth_prior_factor(S(0), np.ones(5), np.r_[0.0, np.ones(4)], 0.1)
