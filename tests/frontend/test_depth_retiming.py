"""Re-timing a frame's depth for a known colour-depth delay (session 17): the re-projection with a full rigid
transform against an exact ray-cast, the sign of the delay, and the colour camera's motion over the delay from
the poses already tracked (constant velocity) or from a finished trajectory's neighbours."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from gsslam.config import load_config
from gsslam.config_schema import ConfigError
from gsslam.frontend.depth_registration import IDENTITY, DepthRegistration, register_frame
from gsslam.frontend.depth_reprojection import reproject_depth
from gsslam.frontend.depth_retiming import DepthRetimer, delay_motion, delay_motions
from gsslam.geometry import interpolate_pose, invert_T, make_T, so3_exp
from gsslam.types import CameraIntrinsics, Frame

INTR = CameraIntrinsics(fx=290.0, fy=290.0, cx=159.5, cy=119.5, width=320, height=240)
FPS = 30.0


def _cast(intr: CameraIntrinsics, T_world_cam: np.ndarray) -> np.ndarray:  # -> [H, W] depth (z), exact
    """A wall z = 3 + 0.2 x and a 0.6 m square box face at z = 1.5 (world), ray-cast from ``T_world_cam``."""
    v, u = np.mgrid[0 : intr.height, 0 : intr.width].astype(np.float64)
    rays = np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones_like(u)], -1)  # [H, W, 3]
    R, c = T_world_cam[:3, :3], T_world_cam[:3, 3]
    d = rays @ R.T  # [H, W, 3] the rays in the world (length: z = 1 in the camera)
    best = np.full(u.shape, np.inf)
    for n, off, bound in (  # planes n . X = off, and where on them the surface is
        (np.array([-0.2, 0.0, 1.0]), 3.0, lambda X: np.ones(X.shape[:-1], bool)),
        (np.array([0.0, 0.0, 1.0]), 1.5, lambda X: (np.abs(X[..., 0]) < 0.3) & (np.abs(X[..., 1]) < 0.3)),
    ):
        s = (off - c @ n) / (d @ n)  # the ray's parameter = the camera's z
        hit = (s > 0) & bound(c + s[..., None] * d) & (s < best)
        best[hit] = s[hit]
    best[~np.isfinite(best)] = np.nan
    return best.astype(np.float32)


def _rel_err_ok(got: np.ndarray, want: np.ndarray, tol: float = 0.01) -> float:
    """Fraction of the pixels with a true depth where ``got`` is within ``tol`` (relative), 12 px inside the
    image border (where the depth camera, turned or moved, saw the scene too)."""
    has = np.zeros(want.shape, bool)
    has[12:-12, 12:-12] = True
    has &= np.isfinite(want)
    return float(np.mean(np.abs(got[has] - want[has]) <= tol * want[has]))


CAM = make_T(np.eye(3), np.array([0.05, -0.02, -0.2]))


@pytest.mark.parametrize("interp_tol", [0.0, 0.03])
def test_full_rigid_transform_matches_the_ray_cast(interp_tol):
    # the depth camera turned 1.5 deg and moved (2, -1, 1.5) cm against the colour camera
    T_cd = make_T(so3_exp(np.radians([0.8, -1.0, 0.6])), np.array([0.02, -0.01, 0.015]))
    depth = _cast(INTR, CAM @ T_cd)  # what the depth camera sees
    want = _cast(INTR, CAM)  # what the colour camera sees
    got = reproject_depth(depth, INTR, INTR, 0.0, 0.0, interp_tol, T_cd[:3, :3], T_cd[:3, 3])
    moved = reproject_depth(depth, INTR, INTR, 0.0, 0.0, interp_tol)  # the transform ignored
    # measured: 99.1 % within 0.5 % (nearest and interpolated), the rest along the box's edges
    assert _rel_err_ok(got, want, 0.005) > 0.98
    assert _rel_err_ok(moved, want, 0.005) < 0.5  # measured 0.35
    inner = np.isfinite(want) & np.isfinite(got)
    bound = 1e-3 if interp_tol == 0 else 1e-5  # measured 1.5e-4 (nearest pixel) / 5e-7 (interpolated)
    assert np.median(np.abs(got[inner] - want[inner]) / want[inner]) < bound


def test_translation_none_is_the_baseline_along_x():
    depth = _cast(INTR, CAM)
    R = so3_exp(np.radians([0.4, -0.5, 0.1]))
    old = reproject_depth(depth, INTR, INTR.with_focal(0.9), 0.025, 0.0, 0.03, R)
    new = reproject_depth(depth, INTR, INTR.with_focal(0.9), 0.025, 0.0, 0.03, R, np.array([0.025, 0, 0]))
    np.testing.assert_array_equal(old, new)  # the same bytes: a given turn runs as before


def _panning(t: float, rate_deg_s: float = 60.0) -> np.ndarray:  # [4, 4] the colour camera at time t
    return CAM @ make_T(so3_exp(np.radians([0.0, rate_deg_s * t, 0.0])), np.array([0.3 * t, 0.0, 0.0]))


def test_a_later_depth_image_is_moved_back_to_the_colour_image():
    tau = 0.016  # depth half a frame after colour, the camera panning 60 deg/s (~1 deg in the delay)
    T_cd = make_T(np.eye(3), np.array([0.025, 0.0, 0.0]))
    reg = DepthRegistration(1.0, 0.025, "depth", ok=True, depth_interp_tol=0.03, delay_s=tau)
    t = 2 / FPS
    frame = Frame(2, t, np.zeros((240, 320, 3)), INTR, _cast(INTR, _panning(t + tau) @ T_cd))
    want = _cast(INTR, _panning(t))
    D = delay_motion(_panning(0), 0.0, _panning(1 / FPS), 1 / FPS, t, tau)  # from the two frames before
    np.testing.assert_allclose(D, invert_T(_panning(t)) @ _panning(t + tau), atol=1e-12)
    retimed = register_frame(frame, reg, D).depth
    as_if_synchronous = register_frame(frame, reg).depth
    backwards = register_frame(frame, reg, invert_T(D)).depth  # the wrong sign: moved further
    ok = [_rel_err_ok(x, want, 0.005) for x in (retimed, as_if_synchronous, backwards)]
    assert ok[0] > 0.98 and ok[1] < 0.6 and ok[2] < ok[1], ok  # measured 0.989 / 0.505 / 0.353
    # the box's left edge: where the colour camera sees it, so does the re-timed depth (+-1 px; measured
    # 76 for 75; taken as synchronous 69, the wrong sign 63)
    row = 120
    edge = lambda d: int(np.argmax(np.nan_to_num(d[row], nan=9.0) < 2.0))  # noqa: E731
    assert abs(edge(retimed) - edge(want)) <= 1 and abs(edge(as_if_synchronous) - edge(want)) >= 4


def test_registered_data_is_retimed_too():
    tau = 0.008
    t = 2 / FPS
    frame = Frame(2, t, np.zeros((240, 320, 3)), INTR, _cast(INTR, _panning(t + tau)))
    D = invert_T(_panning(t)) @ _panning(t + tau)
    reg = replace(IDENTITY, delay_s=tau)
    assert register_frame(frame, reg) is frame  # no motion known: untouched
    out = register_frame(frame, reg, D)
    assert out.intrinsics == INTR and _rel_err_ok(out.depth, _cast(INTR, _panning(t)), 0.005) > 0.98


def _path(t: float) -> np.ndarray:  # constant velocity as interpolate_pose extrapolates it
    A = make_T(so3_exp(np.array([0.1, 0.2, -0.1])), np.array([1.0, 0.5, 2.0]))
    B = make_T(so3_exp(np.array([0.1, 0.25, -0.08])), np.array([1.01, 0.49, 2.005]))
    return interpolate_pose(A, B, t * FPS)


def test_retimer_extrapolates_the_last_two_poses():
    tau = -0.008  # depth before colour
    r = DepthRetimer(tau)
    assert r.motion(0.0) is None
    r.observe(0.0, _path(0.0))
    assert r.motion(1 / FPS) is None  # one pose: no velocity
    r.observe(1 / FPS, _path(1 / FPS))
    t = 2 / FPS
    D = r.motion(t)
    np.testing.assert_allclose(D, invert_T(_path(t)) @ _path(t + tau), atol=1e-9)
    r.observe(t, None)  # not posed: the velocity is lost
    assert r.motion(3 / FPS) is None
    r.observe(3 / FPS, _path(3 / FPS))
    r.observe(4 / FPS, _path(3 / FPS) @ make_T(np.eye(3), np.array([0.5, 0, 0])))  # a jump: 15 m/s
    assert r.motion(5 / FPS) is None
    r.observe(5 / FPS, _path(5 / FPS))
    r.observe(6 / FPS, _path(6 / FPS))
    assert r.motion(9 / FPS) is None  # three frames missing: too far to extrapolate
    assert r.record() == {"delay_s": tau, "frames_retimed": 1, "frames_not_retimed": 5}


def test_retimer_over_more_frames():
    r = DepthRetimer(0.016, span=3)  # the velocity from the 1st and 4th of the last four posed frames
    for k in range(3):
        r.observe(k / FPS, _path(k / FPS))
        assert r.motion((k + 1) / FPS) is None
    r.observe(3 / FPS, _path(3 / FPS))
    want = invert_T(_path(4 / FPS)) @ _path(4 / FPS + 0.016)
    np.testing.assert_allclose(r.motion(4 / FPS), want, atol=1e-9)


def test_delay_motions_of_a_finished_trajectory():
    ts = {i: i / FPS for i in range(5)}
    poses = {i: _path(t) for i, t in ts.items()}
    D = delay_motions(poses, ts, 0.008)
    for i in range(5):  # centred inside, one-sided at the ends: all exact on a constant velocity
        np.testing.assert_allclose(D[i], invert_T(poses[i]) @ _path(ts[i] + 0.008), atol=1e-9)
    alone = delay_motions({0: poses[0], 2: poses[2]}, ts, 0.008)
    np.testing.assert_array_equal(alone[0], np.eye(4))  # no neighbour: no motion


def test_delay_key_is_checked():
    cfg = load_config(None, ["encoder.depth_delay_s=-0.016"], mode="rgbd")
    assert cfg.encoder.depth_delay_s == -0.016
    assert load_config(None, [], mode="rgbd").encoder.depth_delay_s == 0.0  # off by default
    with pytest.raises(ConfigError):
        load_config(None, ["encoder.depth_delay_s=0.5"], mode="rgbd")  # more than a frame or three
