"""GaussianModel: construction checks and exact Sim(3) motion of anchored Gaussians."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from gsslam.geometry import make_T, so3_exp
from gsslam.mapping.gaussians import GaussianError, GaussianModel
from gsslam.mapping.projection import quat_to_rotmat as quat_to_matrix


def _model(n: int, seed: int = 0) -> GaussianModel:
    g = torch.Generator().manual_seed(seed)
    m = GaussianModel.from_points(
        torch.randn(n, 3, generator=g),
        torch.rand(n, 3, generator=g),
        0.01 + torch.rand(n, generator=g) * 0.1,
        submap_id=0,
        keyframe_id=0,
    )
    m.quats = torch.randn(n, 4, generator=g)
    m.log_scales = torch.randn(n, 3, generator=g) * 0.3 - 3
    return m


def test_from_points_round_trips_colour_and_scale():
    rgb = torch.tensor([[0.2, 0.5, 0.9]])
    m = GaussianModel.from_points(torch.zeros(1, 3), rgb, torch.tensor([0.03]), 4, 7, opacity=0.7)
    assert torch.allclose(m.rgb, rgb, atol=1e-6)
    assert torch.allclose(m.scales, torch.full((1, 3), 0.03))
    assert m.opacities.item() == pytest.approx(0.7)
    assert m.submap_id.item() == 4 and m.keyframe_id.item() == 7
    with pytest.raises(GaussianError):
        GaussianModel.from_points(torch.zeros(2, 3), rgb, torch.tensor([0.03]), 0, 0)


def test_apply_transform_moves_only_the_anchored_submap_exactly():
    a, b = _model(50, 0), _model(30, 1)
    b.submap_id[:] = 3
    m = a.cat(b)
    before = m.detached()
    R = so3_exp(np.array([0.3, -0.7, 1.1]))
    t = np.array([0.5, -2.0, 1.0])
    s = 1.7
    T = make_T(R, t, s)
    moved = m.apply_transform(3, T)
    assert moved == 30
    sel = m.submap_id == 3
    # the other submap is untouched
    for name in ("means", "quats", "log_scales", "opacity_logits", "sh_dc"):
        assert torch.equal(getattr(m, name)[~sel], getattr(before, name)[~sel])
    Rt = torch.as_tensor(R, dtype=torch.float32)
    exp_means = s * before.means[sel] @ Rt.T + torch.as_tensor(t, dtype=torch.float32)
    assert torch.allclose(m.means[sel], exp_means, atol=1e-5)
    assert torch.allclose(quat_to_matrix(m.quats[sel]), Rt @ quat_to_matrix(before.quats[sel]), atol=1e-5)
    assert torch.allclose(m.log_scales[sel], before.log_scales[sel] + math.log(s), atol=1e-6)
    assert torch.equal(m.sh_dc, before.sh_dc) and torch.equal(m.opacity_logits, before.opacity_logits)
    # the inverse transform brings everything back
    m.apply_transform(3, np.linalg.inv(T))
    assert torch.allclose(m.means, before.means, atol=1e-5)
    assert torch.allclose(m.log_scales, before.log_scales, atol=1e-6)
    assert torch.allclose(quat_to_matrix(m.quats), quat_to_matrix(before.quats), atol=1e-5)


def test_apply_transform_rejects_non_similarity():
    m = _model(3)
    T = np.eye(4)
    T[0, 1] = 0.5  # shear
    with pytest.raises(GaussianError):
        m.apply_transform(0, T)
    assert m.apply_transform(9, np.eye(4)) == 0


def test_select_and_cat_keep_fields_aligned():
    m = _model(10)
    m.submap_id = torch.arange(10)
    sub = m.select(torch.tensor([1, 5]))
    assert len(sub) == 2 and sub.submap_id.tolist() == [1, 5]
    assert torch.equal(sub.means, m.means[[1, 5]])
    both = sub.cat(m)
    assert len(both) == 12 and both.size_bytes() == 12 * 17 * 4
    with pytest.raises(GaussianError):
        GaussianModel(
            m.means, m.quats[:3], m.log_scales, m.opacity_logits, m.sh_dc, m.submap_id, m.keyframe_id
        )
