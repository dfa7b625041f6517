"""Depth-to-colour registration on real TUM teddy frames with simulated unregistered Kinect v1 depth:
the focal ratio, the baseline and whose intrinsics the dataset gave are recovered both when it gives
the colour camera's and when it gives the depth camera's (7-Scenes); registered data is left alone."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from gsslam.config import FlowConfig
from gsslam.datasets.misregistered import misregister_depth
from gsslam.frontend.depth_registration import (
    IDENTITY,
    DepthRegistration,
    register_frame,
    registration_correction,
    reproject_depth,
)
from gsslam.frontend.flow import make_flow_estimator
from helpers.tum import TUM_FR3, load_tum

KINECT_RATIO = 1.114  # 585 / 525: depth focal over colour focal of a Kinect v1
BASELINE_M = 0.025


@pytest.fixture(scope="module")
def teddy(bundled_tum):
    return [f for f in load_tum(bundled_tum, list(range(0, 30))) if f.depth is not None]


def _misregistered(frames, report: str):
    intr = (
        TUM_FR3
        if report == "colour"
        else replace(TUM_FR3, fx=TUM_FR3.fx * KINECT_RATIO, fy=TUM_FR3.fy * KINECT_RATIO)
    )
    return [
        replace(f, depth=misregister_depth(f.depth, TUM_FR3, BASELINE_M, KINECT_RATIO), intrinsics=intr)
        for f in frames
    ]


def _correct(frames):
    return registration_correction(
        frames, make_flow_estimator(FlowConfig()), min_dev=0.02, min_baseline_m=0.01
    )


@pytest.mark.slow  # ~35 s CPU each: the colour hypothesis reruns ICP on 15 focal lengths x 12 pairs
@pytest.mark.parametrize("report", ["colour", "depth"])
def test_misregistration_recovered(teddy, report):
    frames = _misregistered(teddy, report)
    reg, est = _correct(frames)
    assert reg is est and est.ok and est.pairs >= 3
    assert est.given == report  # measured costs 0.96 vs 1.28 px (colour given), 0.96 vs 1.35 px (depth given)
    # measured on 40 frames: k 1.108 / 1.126, baseline 26.4 / 25.9 mm (colour / depth given)
    assert abs(est.ratio / KINECT_RATIO - 1) < 0.015, est
    assert abs(est.baseline_m - BASELINE_M) < 0.005, est
    assert est.cost < 0.6 * est.cost_registered  # measured 0.96 vs 1.84 / 1.99 px
    assert reg.colour_intrinsics(frames[0].intrinsics).fx == pytest.approx(TUM_FR3.fx, rel=0.015)


def test_registered_data_is_left_alone(teddy):
    reg, est = _correct(teddy)
    assert reg is IDENTITY and est.ok
    assert abs(est.ratio - 1) < 0.01 and abs(est.baseline_m) < 0.01, est  # measured 1.002, -4 mm (40 frames)


def test_reproject_depth_undoes_the_misregistration(teddy):
    f = teddy[0]
    mis = misregister_depth(f.depth, TUM_FR3, BASELINE_M, KINECT_RATIO)
    reg = DepthRegistration(KINECT_RATIO, BASELINE_M, "colour")
    depth_intr = reg.depth_intrinsics(TUM_FR3)
    assert (
        depth_intr.fx == pytest.approx(TUM_FR3.fx * KINECT_RATIO)
        and reg.colour_intrinsics(TUM_FR3) == TUM_FR3
    )
    back = reproject_depth(mis, depth_intr, TUM_FR3, BASELINE_M)
    ok = np.isfinite(back) & np.isfinite(f.depth)
    assert ok.mean() > 0.6  # the depth camera sees ~81 % of the colour view
    rel = np.abs(back[ok] - f.depth[ok]) / f.depth[ok]
    assert np.median(rel) < 1e-3 and np.mean(rel < 0.02) > 0.95
    g = register_frame(replace(f, depth=mis), reg)
    assert g.intrinsics == TUM_FR3 and g.image is f.image
    assert np.array_equal(np.isfinite(g.depth), np.isfinite(back))
    assert register_frame(f, IDENTITY) is f


def test_reproject_depth_mean_of_the_nearest_surface_removes_the_noise_minimum():
    """Kinect v1 depth (1.114x the colour focal) lands ~1.24 samples on each colour pixel: the nearest of
    two noisy samples of one wall is biased towards the camera; their mean is not, and a nearer surface
    still wins over a farther one."""
    depth_intr = replace(TUM_FR3, fx=TUM_FR3.fx * KINECT_RATIO, fy=TUM_FR3.fy * KINECT_RATIO)
    rng = np.random.default_rng(0)
    wall = (3.0 + rng.normal(0.0, 0.013, (TUM_FR3.height, TUM_FR3.width))).astype(np.float32)  # ~z^2 at 3 m
    nearest = reproject_depth(wall, depth_intr, TUM_FR3, BASELINE_M)
    mean = reproject_depth(wall, depth_intr, TUM_FR3, BASELINE_M, mean_tol=0.03)
    assert np.array_equal(np.isfinite(nearest), np.isfinite(mean))
    # measured -1.7 mm (nearest) and -0.04 mm (mean) over the wall
    assert np.nanmean(nearest) - 3.0 < -0.001 and abs(np.nanmean(mean) - 3.0) < 0.0003
    step = wall.copy()
    step[:, : TUM_FR3.width // 2] = 1.5  # a nearer surface on the left: the wall behind is not mixed in
    both = reproject_depth(step, depth_intr, TUM_FR3, BASELINE_M, mean_tol=0.03)
    assert np.nanmax(both[both < 2.0]) == pytest.approx(1.5)


def test_reproject_depth_interpolated_at_the_exact_pixel():
    """A slanted plane seen by the depth camera, re-projected into the colour camera: each sample lands on
    its nearest pixel (up to half a pixel off, 0.85 mm RMS here); read at the exact depth pixel, 0.05 mm."""
    depth_intr = replace(TUM_FR3, fx=TUM_FR3.fx * KINECT_RATIO, fy=TUM_FR3.fy * KINECT_RATIO)
    u = np.arange(TUM_FR3.width)[None, :] + np.zeros((TUM_FR3.height, 1))
    truth = 1.5 / (1 - 0.8 * (u - TUM_FR3.cx) / TUM_FR3.fx)  # z = 1.5 + 0.8 x in the colour camera
    seen = (1.5 + 0.8 * BASELINE_M) / (1 - 0.8 * (u - depth_intr.cx) / depth_intr.fx)  # the same plane
    rms = []
    for tol in (0.0, 0.03):
        out = reproject_depth(seen.astype(np.float32), depth_intr, TUM_FR3, BASELINE_M, interp_tol=tol)
        ok = np.isfinite(out)
        rms.append(float(np.sqrt(np.mean((out[ok] - truth[ok]) ** 2))))
    assert rms[0] > 5e-4 and rms[1] < 1e-4, rms  # measured 0.85 mm and 0.045 mm


def test_reproject_depth_undoes_a_turned_depth_camera(teddy):
    """A depth camera turned as the LIRIS Kinect v1 calibration says (0.47 / -0.45 / -0.16 deg): the
    registration that turns the cloud back (``depth_rotation_deg``) undoes it; along x alone leaves 4.7 px."""
    f = teddy[0]
    rot = (0.468, -0.452, -0.155)
    mis = misregister_depth(f.depth, TUM_FR3, BASELINE_M, KINECT_RATIO, rotation_deg=rot)
    along_x = DepthRegistration(KINECT_RATIO, BASELINE_M, "colour")
    turned = replace(along_x, depth_rotation_deg=rot)
    assert along_x.R_colour_depth() is None and not turned.is_identity()
    assert np.allclose(turned.R_colour_depth() @ turned.R_colour_depth().T, np.eye(3))

    def errors(reg: DepthRegistration, tol: float) -> np.ndarray:  # relative error where both have depth
        back = reproject_depth(mis, reg.depth_intrinsics(TUM_FR3), TUM_FR3, BASELINE_M, interp_tol=tol,
                               R_colour_depth=reg.R_colour_depth())  # fmt: skip
        ok = np.isfinite(back) & np.isfinite(f.depth)
        return np.abs(back[ok] - f.depth[ok]) / f.depth[ok]

    for tol in (0.0, 0.03):  # nearest pixel, and read at the exact depth pixel
        e_x, e_turned = errors(along_x, tol), errors(turned, tol)
        # measured: median 0.80 % -> 0.002 %, within 2 %: 85.6 % -> 98.3 / 99.0 % (unrotated 98.4 %)
        assert np.median(e_x) > 0.006 and np.median(e_turned) < 1e-3
        assert np.mean(e_x < 0.02) < 0.9 and np.mean(e_turned < 0.02) > 0.97
    g = register_frame(replace(f, depth=mis), turned)
    assert np.array_equal(
        g.depth, reproject_depth(mis, TUM_FR3.with_focal(KINECT_RATIO), TUM_FR3, BASELINE_M,
                                 R_colour_depth=turned.R_colour_depth()), equal_nan=True,
    )  # fmt: skip
