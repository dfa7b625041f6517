"""Owners of the converged map: which submaps' Gaussians explain a view (relative registrations)."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from gsslam.config import MapperConfig
from gsslam.mapping.mapper import GaussianMapper

CFG = MapperConfig(max_side=120, iterations=10, window=4, device="cpu", feedback_min_age=0)


@pytest.fixture(scope="module")
def two_submap_map(teddy_frames):
    """f0 seeds submap 3, f3 (15 frames later) submap 8: two owners of overlapping views."""
    f0, f3 = teddy_frames[0], teddy_frames[3]
    torch.manual_seed(0)
    m = GaussianMapper(CFG, f0.intrinsics)
    m.add_keyframe(f0, f0.T_world_cam_gt, 3)
    m.add_keyframe(f3, f3.T_world_cam_gt, 8)
    m.optimize(10)
    return m


def test_owners_share_the_view_by_rendered_weight(two_submap_map, teddy_frames):
    """At f0's pose submap 3 (f0's own Gaussians) owns almost all of the view; at f3's, submap 8 owns a
    real part (f3 seeds only where f0's Gaussians left its view unmapped: measured 0.35); the shares of the
    converged view add up to one."""
    f0, f3 = teddy_frames[0], teddy_frames[3]
    at0 = two_submap_map.registration_owners(f0.T_world_cam_gt)
    at3 = two_submap_map.registration_owners(f3.T_world_cam_gt)
    assert set(at0) <= {3, 8} and set(at3) <= {3, 8}
    assert sum(at0.values()) == pytest.approx(1.0, abs=1e-3)
    assert sum(at3.values()) == pytest.approx(1.0, abs=1e-3)
    assert at0[3] > 0.9, at0
    assert 0.2 < at3[8] < 0.5 and at3[8] > 3 * at0.get(8, 0.0), (at0, at3)


def test_only_converged_gaussians_own(two_submap_map, teddy_frames):
    """With min_age=1 only f0's Gaussians (submap 3) are converged: they own all of what they cover; with
    min_age=2 nothing is converged and there is no owner."""
    f3 = teddy_frames[3]
    for age, want in ((1, {3}), (2, set())):
        m = GaussianMapper.__new__(GaussianMapper)
        m.cfg = dataclasses.replace(two_submap_map.cfg, feedback_min_age=age)
        m.map = dataclasses.replace(two_submap_map.map, cfg=m.cfg)
        owners = m.registration_owners(f3.T_world_cam_gt)
        assert set(owners) == want
        if want:
            assert owners[3] == pytest.approx(1.0, abs=1e-3)
