"""Densify/prune strategy: invariants of the model and its state dict."""

from __future__ import annotations

import math

import pytest
import torch

from gsslam.mapping.densify import STATE_KEYS, DensifyError, DensifyStrategy
from gsslam.mapping.gaussians import GaussianModel


def _model(n: int) -> GaussianModel:
    g = torch.Generator().manual_seed(0)
    return GaussianModel.from_points(
        torch.randn(n, 3, generator=g),
        torch.rand(n, 3, generator=g),
        torch.full((n,), 0.05),
        submap_id=0,
        keyframe_id=0,
        opacity=0.5,
    )


def _observe(strategy, state, errors, radii, times=3):
    for _ in range(times):
        strategy.update_state(state, errors, radii)


def _check(model, state):
    for k in STATE_KEYS:
        assert state[k].shape == (len(model),)


def test_high_error_gaussians_are_cloned_or_split_low_ones_kept():
    s = DensifyStrategy(densify_error=0.5, prune_error=5.0, split_radius_px=4.0, max_gaussians=100)
    m = _model(10)
    state = s.initialize_state(10)
    err = torch.tensor([0.1] * 6 + [1.0, 1.0, 1.0, 1.0])
    radii = torch.tensor([3.0] * 8 + [6.0, 6.0])
    _observe(s, state, err, radii)
    m2, st2, stats = s.step(m, state)
    assert stats["cloned"] == 2 and stats["split"] == 2 and stats["pruned"] == 0
    assert len(m2) == 10 + 2 + 2  # clones add one each, splits replace one by two
    _check(m2, st2)
    # split children are smaller by split_factor; clones are exact copies with reset error stats
    assert torch.allclose(m2.log_scales[-4:], torch.full((4, 3), math.log(0.05 / s.split_factor)), atol=1e-6)
    assert torch.equal(m2.means[8:10], m.means[6:8])
    assert st2["err_count"][8:].sum() == 0


def test_low_opacity_and_inconsistent_gaussians_are_pruned():
    s = DensifyStrategy(densify_error=10.0, prune_error=2.0, min_opacity=0.1, max_gaussians=100)
    m = _model(6)
    m.opacity_logits[0] = -5.0  # opacity ~0.007
    state = s.initialize_state(6)
    err = torch.tensor([0.1, 3.0, 0.1, 0.1, 0.1, 0.1])
    _observe(s, state, err, torch.full((6,), 2.0))
    m2, st2, stats = s.step(m, state)
    assert stats["pruned"] == 2 and len(m2) == 4
    assert (m2.opacities >= 0.1).all()
    assert torch.allclose(m2.means, m.means[2:])
    _check(m2, st2)


def test_unseen_gaussians_are_pruned_only_when_active_and_old():
    s = DensifyStrategy(min_age=2, min_support=1, max_gaussians=100)
    m = _model(4)
    state = s.initialize_state(4)
    active = torch.tensor([True, True, False, False])
    s.update_state(
        state, torch.tensor([0.1, float("nan"), float("nan"), float("nan")]), torch.tensor([2.0, 0, 0, 0])
    )
    m, state, st = s.step(m, state, active=active)
    assert len(m) == 4  # too young
    m, state, st = s.step(m, state, active=active)
    assert len(m) == 3 and st["pruned"] == 1  # Gaussian 1: active, never seen; 2, 3 inactive
    assert state["age"].tolist() == [2.0, 0.0, 0.0]


def test_count_cap_is_respected():
    s = DensifyStrategy(densify_error=0.5, max_gaussians=12)
    m = _model(10)
    m.opacity_logits = torch.linspace(-2, 2, 10)
    state = s.initialize_state(10)
    _observe(s, state, torch.ones(10), torch.full((10,), 2.0))
    m2, st2, stats = s.step(m, state)
    assert len(m2) == 12 and stats["cloned"] == 2
    _check(m2, st2)
    # a model already above the cap loses its least opaque Gaussians
    s_small = DensifyStrategy(max_gaussians=5)
    m3, st3, stats3 = s_small.step(m, s_small.initialize_state(10))
    assert len(m3) == 5 and stats3["capped"] == 5
    assert torch.allclose(m3.opacity_logits.sort().values, m.opacity_logits[5:])
    _check(m3, st3)


def test_state_must_match_model():
    s = DensifyStrategy()
    with pytest.raises(DensifyError):
        s.step(_model(3), s.initialize_state(4))
    state = s.grow_state(s.initialize_state(3), 2)
    _check(_model(5), state)
