"""The Kinect v1 depth model: noise ~ z^2, disparity quantization, holes; the long synthetic room."""

from __future__ import annotations

import numpy as np
import pytest

from gsslam.datasets.depth_sensor import DepthSensorError, KinectV1, kinect_v1_depth
from gsslam.datasets.synthetic import SyntheticDataset
from gsslam.datasets.synthetic.presets import FURNISHED_HALF
from gsslam.datasets.synthetic.trajectories import room_walk
from gsslam.types import CameraIntrinsics

INTR = CameraIntrinsics(200.0, 200.0, 99.5, 74.5, 200, 150)
NOISE_ONLY = dict(disparity_k=0.0, max_range_m=0.0, min_range_m=0.0, max_incidence_deg=90.0, edge_band_px=0)


def _plane(z: float) -> np.ndarray:  # a fronto-parallel wall at z [150, 200]
    return np.full((INTR.height, INTR.width), z, np.float64)


@pytest.mark.parametrize("z", [1.0, 3.0])
def test_noise_std_grows_with_z_squared(z):
    out = kinect_v1_depth(_plane(z), INTR, KinectV1(**NOISE_ONLY), np.random.default_rng(0))
    err = out.astype(np.float64) - z
    assert np.isfinite(err).all()
    assert abs(err.mean()) < 0.02 * 1.43e-3 * z * z
    assert err.std() == pytest.approx(1.43e-3 * z * z, rel=0.03)  # 30000 pixels: ~0.4 % standard error


def test_disparity_quantization_steps_as_z_squared():
    sensor = KinectV1(**{**NOISE_ONLY, "sigma_z2": 0.0, "disparity_k": 348.0})
    z = np.linspace(0.8, 3.9, INTR.width)[None, :].repeat(INTR.height, 0)
    out = kinect_v1_depth(z, INTR, sensor, np.random.default_rng(0)).astype(np.float64)
    d = 348.0 / out
    np.testing.assert_allclose(d, np.round(d), atol=1e-3)  # every depth on the 1/8 px disparity lattice
    step = z * z / 348.0
    assert np.all(np.abs(out - z) <= 0.5 * step * 1.05 + 1e-6)  # within half a step of the truth
    levels = np.unique(np.round(out[0, out[0] > 3.5], 5))
    assert np.diff(levels).min() == pytest.approx(3.5**2 / 348.0, rel=0.15)  # ~3.5 cm apart near 3.5 m


def test_holes_at_range_limits_grazing_angles_and_depth_edges():
    sensor = KinectV1(sigma_z2=0.0, disparity_k=0.0)  # the default holes, no noise
    z = _plane(2.0)
    z[:, :40] = 4.5  # beyond 4 m
    z[:, 40:60] = 0.4  # nearer than 0.5 m
    out = kinect_v1_depth(z, INTR, sensor, np.random.default_rng(0))
    assert np.isnan(out[:, :60]).all()
    assert np.isfinite(out[2:-2, 64:-2]).all()  # the band: 2 px beside the 0.4 -> 2.0 m edge
    assert np.isnan(out[:, 60:62]).all()
    # a step from 1 to 1.5 m: both sides lose a band of edge_band_px, nothing else does
    step = _plane(1.0)
    step[:, 100:] = 1.5
    out = kinect_v1_depth(step, INTR, sensor, np.random.default_rng(0))
    holes = np.isnan(out[10:-10]).any(0)
    assert np.flatnonzero(holes).tolist() == [98, 99, 100, 101]
    # planes tilted about the camera's y axis: 60 deg incidence keeps its depth, 80 deg does not
    for angle, valid in ((60.0, True), (80.0, False)):
        x = (np.arange(INTR.width) - INTR.cx) / INTR.fx  # ray x / z
        t = np.tan(np.deg2rad(angle))
        zz = 2.0 / (1.0 - x * t)  # the plane z = 2 + X tan(angle) along each ray (positive where hit)
        tilted = np.where(zz > 0, zz, np.nan)[None, :].repeat(INTR.height, 0)
        tilted = np.where(tilted < 3.9, tilted, 2.0)  # keep inside range
        sensor_i = KinectV1(sigma_z2=0.0, disparity_k=0.0, max_range_m=0.0, edge_band_px=0)
        out = kinect_v1_depth(tilted, INTR, sensor_i, np.random.default_rng(0))
        centre = out[10:-10, INTR.width // 2 - 5 : INTR.width // 2 + 5]
        assert np.isfinite(centre).all() == valid, angle


def test_deterministic_with_the_generator_and_parsed_from_specs():
    z = _plane(2.0)
    a = kinect_v1_depth(z, INTR, KinectV1(), np.random.default_rng(4))
    b = kinect_v1_depth(z, INTR, KinectV1(), np.random.default_rng(4))
    c = kinect_v1_depth(z, INTR, KinectV1(), np.random.default_rng(5))
    np.testing.assert_array_equal(a, b)
    assert np.nanmean(np.abs(a - c)) > 1e-3
    assert KinectV1.from_spec("kinect_v1") == KinectV1()
    assert KinectV1.from_spec({"model": "kinect_v1", "edge_band_px": 3}).edge_band_px == 3
    assert KinectV1.from_spec(None) is None
    for bad in ("kinect_v2", {"sigma": 1.0}, {"dropout": 1.5}):
        with pytest.raises(DepthSensorError):
            KinectV1.from_spec(bad)


def test_room_walk_explores_and_revisits_inside_the_room():
    P = room_walk(1000, seed=0)
    pos = P[:, :3, 3]
    assert np.all(np.abs(pos) < FURNISHED_HALF - 0.5)
    steps = np.linalg.norm(np.diff(pos, axis=0), axis=1)
    assert 10.0 < steps.sum() < 14.0  # measured 12.1 m
    assert np.percentile(steps, 5) < 0.004 and steps.max() < 0.03  # stops and quick parts
    ang = np.unwrap(np.arctan2(pos[:, 0], pos[:, 2]))
    turns = np.flatnonzero(np.diff(np.sign(np.diff(ang[::10]))) != 0)
    assert len(turns) >= 3  # the walk reverses round the room (measured: 3 reversals and a stop, 4 changes)
    view = P[:, :3, 2]  # viewing directions: the room's walls are seen looking both ways
    assert (view[:, 0] > 0.8).any() and (view[:, 0] < -0.8).any()
    np.testing.assert_array_equal(P, room_walk(1000, seed=0))
    assert np.abs(P - room_walk(1000, seed=1)).max() > 1e-3  # the hand shake is drawn from the seed


def test_kinect_room_frames_are_deterministic_and_default_frames_unchanged():
    kw = dict(n_frames=40, width=96, height=72, scene="furnished_room", trajectory="room_walk", seed=1)
    exact = SyntheticDataset(**kw)
    hand = dict(
        sensor="kinect_v1",
        misregister={"baseline_m": 0.025, "focal_scale": 1.114, "report": "depth"},
        degrade={"shutter": 0.5, "exposure_amp": 0.25, "exposure_period": 150},
    )
    a, b = SyntheticDataset(**kw, **hand)[7], SyntheticDataset(**kw, **hand)[7]
    np.testing.assert_array_equal(a.image, b.image)
    np.testing.assert_array_equal(a.depth, b.depth)
    e = exact[7]
    assert a.intrinsics.fx == pytest.approx(1.114 * e.intrinsics.fx)  # handed out as 7-Scenes does
    np.testing.assert_array_equal(a.T_world_cam_gt, e.T_world_cam_gt)
    assert np.isfinite(e.depth).all() and not np.isfinite(a.depth).all()
    assert np.abs(a.image - e.image).mean() > 0.005  # blurred and exposed
    noise_only = SyntheticDataset(**kw, sensor="kinect_v1")[7]
    np.testing.assert_array_equal(noise_only.image, e.image)  # the sensor touches the depth only
    ok = np.isfinite(noise_only.depth)
    rel = np.abs(noise_only.depth[ok] - e.depth[ok]) / e.depth[ok] ** 2
    assert 0.5 < ok.mean() < 1.0 and np.median(rel) < 5e-3
    with pytest.raises(DepthSensorError):
        SyntheticDataset(**kw, sensor="nope")


def test_misregistered_depth_ray_cast_from_the_depth_camera():
    """``misregister.raycast``: the depth camera itself (25 mm beside colour, 1.114x focal) is ray-cast; the
    default re-projection's splat (nearest of 4 pixels) sits nearer on slanted surfaces (session 13)."""
    kw = dict(n_frames=220, width=160, height=120, scene="furnished_room", trajectory="room_walk", seed=0)
    mis = {"baseline_m": 0.025, "focal_scale": 1.114, "report": "depth"}
    splat = SyntheticDataset(**kw, misregister=mis)[200]
    cast = SyntheticDataset(**kw, misregister={**mis, "raycast": True})[200]
    assert cast.intrinsics == splat.intrinsics and np.isfinite(cast.depth).all()
    d = (splat.depth - cast.depth)[np.isfinite(splat.depth)]
    # measured at 320x240, frame 200: median -1.5 mm, mean -2.3 mm (the splat's near bias); edges aside
    assert np.median(np.abs(d)) < 0.01 and np.median(d) < 0.0
    exact = SyntheticDataset(**kw)[200].depth
    assert np.median(np.abs(cast.depth - exact)) > 1e-3  # not the colour camera's depth
