"""A mono loop's lateral extent (gsslam.loop.extent) and the sigma factor it sets (loop.mono_extent_sigma)."""

from __future__ import annotations

import dataclasses

import numpy as np

from gsslam.config import LoopConfig
from gsslam.geometry import make_T, so3_exp, umeyama
from gsslam.loop import LoopConstraint
from gsslam.loop.extent import lateral_extent_rel
from gsslam.loop.weights import loop_weight


def _patch(rng, width_x, width_y, n=300, z=3.0, relief=0.2):  # [n, 3] a patch in front of the camera
    X = np.column_stack([rng.uniform(-width_x, width_x, n), rng.uniform(-width_y, width_y, n), np.full(n, z)])
    X[:, 2] += relief * np.sin(3 * X[:, 0]) * np.cos(2 * X[:, 1])
    return X


def _rot_deg(Ta, Tb):
    Ra = Ta[:3, :3] / np.cbrt(np.linalg.det(Ta[:3, :3]))
    Rb = Tb[:3, :3] / np.cbrt(np.linalg.det(Tb[:3, :3]))
    return float(np.degrees(np.arccos(np.clip((np.trace(Ra.T @ Rb) - 1) / 2, -1, 1))))


def test_extent_is_the_middle_principal_std_over_the_range_and_unit_free():
    rng = np.random.default_rng(0)
    flat = _patch(rng, 1.0, 0.05, relief=0.0)  # 2 m long, 10 cm wide, flat, 3 m away
    assert abs(lateral_extent_rel(flat) - (0.1 / np.sqrt(12)) / 3.0) < 0.002  # uniform over 0.1 m: std 0.029
    strip = _patch(rng, 1.0, 0.05)  # with relief: its depth spread is the middle axis
    assert lateral_extent_rel(strip) < 0.05
    wide = _patch(rng, 1.0, 1.0)
    assert lateral_extent_rel(wide) > 0.15
    R = so3_exp(np.array([0.3, -0.2, 0.1]))
    for X in (strip, wide):  # mono units are arbitrary: scale and a turn about the camera leave it
        assert np.isclose(lateral_extent_rel(7.0 * X), lateral_extent_rel(X))
        assert np.isclose(lateral_extent_rel(X @ R.T), lateral_extent_rel(X))
    assert lateral_extent_rel(strip[:2]) == 0.0


def test_a_narrow_loop_turns_with_a_smooth_depth_error_that_a_wide_one_averages():
    """The mechanism (session 12): the point maps of a mono loop disagree by a smooth, correlated depth
    error, which does not average over the points; the Sim(3) fitted to a narrow strip takes it as a
    rotation of degrees, a wide patch's fit much less. Real loops: extent below 0.1 -> 2.6-3.2 deg off
    (median), the others 1.0-1.4 deg (docs/results.md, "Mono loops to the first submap, session 12")."""
    T = make_T(so3_exp(np.array([0.05, -0.1, 0.2])), np.array([0.3, 0.1, -0.2]), 1.2)
    errs = {"strip": [], "wide": []}
    for seed in range(20):
        rng = np.random.default_rng(seed)
        k, ph = rng.uniform(1.0, 2.0, 2), rng.uniform(0, 2 * np.pi, 2)
        for name, wy in (("strip", 0.05), ("wide", 1.0)):
            X_m = _patch(rng, 1.0, wy)
            # <= 2 % depth error along the rays, smooth over 0.3-0.6 m across the strip (one submap's
            # triangulation against the other's): a tilt over a 10 cm strip, an average over a 2 m patch
            e = 0.02 * np.sin(k[0] * X_m[:, 0] + ph[0]) * np.sin(k[1] * X_m[:, 1] * 10 + ph[1])
            X_i = (X_m * (1 + e)[:, None]) @ T[:3, :3].T + T[:3, 3]
            errs[name].append(_rot_deg(umeyama(X_m, X_i, with_scale=True), T))
    strip, wide = np.median(errs["strip"]), np.median(errs["wide"])
    assert strip > 1.5  # measured: 2.65 deg
    assert wide < 0.2 * strip  # measured: 0.27 deg


def test_mono_extent_sigma_scales_a_narrow_loops_sigmas_only():
    rng = np.random.default_rng(3)
    T = make_T(so3_exp(np.array([0.1, -0.2, 0.3])), np.array([0.5, 0.0, -1.0]), 1.3)

    def loop(X_m):
        X_i = X_m @ T[:3, :3].T * 1.0 + T[:3, 3] + 0.01 * rng.standard_normal(X_m.shape)
        return LoopConstraint(0, 5, X_i, X_m, umeyama(X_m, X_i, with_scale=True), 0.5, 0.8, 0.1)

    narrow, wide = loop(_patch(rng, 1.0, 0.05)), loop(_patch(rng, 1.0, 1.0))
    off, on = LoopConfig(), dataclasses.replace(LoopConfig(), mono_extent_sigma=0.1)
    assert off.mono_extent_sigma == 0.0  # opt-in
    w0, w1 = loop_weight(narrow, "mono", off), loop_weight(narrow, "mono", on)
    f = 0.1 / lateral_extent_rel(narrow.X_i)
    assert f > 2.0
    assert np.isclose(w1.sigma, f * w0.sigma) and np.isclose(w1.sigma_perp, f * w0.sigma_perp)
    assert loop_weight(wide, "mono", on) == loop_weight(wide, "mono", off)  # wide enough: unchanged
    assert loop_weight(narrow, "rgbd", on) is None  # RGB-D: metric loops, untouched
