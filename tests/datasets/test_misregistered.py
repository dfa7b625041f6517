"""The simulated depth camera's rotation and offset against the colour camera (session 16): which way they go,
that the re-projection and the ray-cast agree, and that zero changes nothing."""

import numpy as np
import pytest

from gsslam.datasets.misregistered import Misregistration, MisregistrationError, misregister_depth
from gsslam.datasets.synthetic import SyntheticDataset
from gsslam.types import CameraIntrinsics

K = CameraIntrinsics(500.0, 500.0, 79.5, 59.5, 160, 120)
LIRIS_DEG = (0.468, -0.452, -0.155)  # the LIRIS Kinect v1 calibration's R_colour_depth as a rotation vector


def _cross_depth() -> np.ndarray:  # [H, W] a wall at 2 m with a near box (1 m) in the upper-left quadrant
    d = np.full((120, 160), 2.0, dtype=np.float32)
    d[:60, :80] = 1.0
    return d


def _edges(out: np.ndarray) -> tuple[int, int]:  # (first wall column on row 30, first wall row on column 40)
    return int(np.flatnonzero(out[30] > 1.5)[0]), int(np.flatnonzero(out[:, 40] > 1.5)[0])


def test_zero_rotation_and_offset_change_nothing():
    d = _cross_depth()
    d[5:9, 100:104] = np.nan
    plain = misregister_depth(d, K, baseline_m=0.02, focal_scale=1.1)
    zero = misregister_depth(d, K, 0.02, 1.1, rotation_deg=(0.0, 0.0, 0.0), offset_m=(0.0, 0.0))
    assert np.array_equal(plain, zero, equal_nan=True)
    assert Misregistration().is_along_x()
    assert np.array_equal(Misregistration(baseline_m=0.02).T_colour_depth()[:3, 3], [0.02, 0.0, 0.0])


def test_rotation_about_y_moves_every_depth_the_same_way_along_u():
    d = _cross_depth()
    u0, v0 = _edges(misregister_depth(d, K, 0.0, 1.0))
    # ry > 0: the depth camera looks towards +x, so what the colour camera sees at u appears at u - f tan(ry)
    ry = 0.5
    out = misregister_depth(d, K, 0.0, 1.0, rotation_deg=(0.0, ry, 0.0))
    u1, v1 = _edges(out)
    shift = 500.0 * np.tan(np.radians(ry))  # 4.4 px, the same at 1 m and 2 m (no parallax in a rotation)
    assert abs((u1 - u0) + shift) <= 1.0 and abs(v1 - v0) <= 1
    assert np.nanmedian(out[80:, 100:]) == pytest.approx(2.0, abs=2e-3)  # a fronto-parallel wall stays ~2 m


def test_rotation_about_x_moves_along_v():
    d = _cross_depth()
    u0, v0 = _edges(misregister_depth(d, K, 0.0, 1.0))
    rx = 0.5  # rx > 0: the depth camera looks towards -y, what the colour camera sees at v appears lower
    u1, v1 = _edges(misregister_depth(d, K, 0.0, 1.0, rotation_deg=(rx, 0.0, 0.0)))
    assert abs((v1 - v0) - 500.0 * np.tan(np.radians(rx))) <= 1.0 and abs(u1 - u0) <= 1


def test_offset_along_z_brings_the_depth_camera_nearer():
    d = np.full((120, 160), 2.0, dtype=np.float32)
    out = misregister_depth(d, K, 0.0, 1.0, offset_m=(0.0, 0.002))  # the depth camera 2 mm ahead
    assert np.nanmedian(out) == pytest.approx(1.998, abs=1e-5)
    down = misregister_depth(d, K, 0.0, 1.0, offset_m=(0.01, 0.0))  # 1 cm lower (+y): the wall slides up
    assert np.isnan(down[-1, 80]) and np.isfinite(down[0, 80])  # its bottom rows see nothing


def test_from_dict_reads_lists_and_refuses_bad_ones():
    mr = Misregistration.from_dict({"rotation_deg": [0.5, -0.4, 0.1], "offset_m": [0, 0.002]})
    assert mr.rotation_deg == (0.5, -0.4, 0.1) and mr.offset_m == (0.0, 0.002) and not mr.is_along_x()
    R = mr.T_colour_depth()[:3, :3]
    assert np.allclose(R @ R.T, np.eye(3)) and R[0, 2] == pytest.approx(np.radians(-0.4), abs=1e-5)
    with pytest.raises(MisregistrationError):
        Misregistration(rotation_deg=(0.5, 0.1))
    with pytest.raises(MisregistrationError):
        Misregistration(rotation_deg=(45.0, 0.0, 0.0))
    with pytest.raises(MisregistrationError):
        Misregistration(offset_m=(float("nan"), 0.0))


def test_raycast_and_reprojection_agree_on_the_rotated_depth_camera():
    """The two paths of the synthetic scene put the rotated, offset depth camera in the same place."""
    common = dict(n_frames=3, width=160, height=120, scene="furnished_room", trajectory="room_walk")
    mr = {"baseline_m": 0.025, "focal_scale": 1.114, "rotation_deg": list(LIRIS_DEG), "offset_m": [0, 0.002]}

    def depth(**kw) -> np.ndarray:
        return SyntheticDataset(**common, misregister={**mr, **kw})[1].depth

    def rel(a: np.ndarray, b: np.ndarray) -> float:  # median relative difference where both have depth
        both = np.isfinite(a) & np.isfinite(b)
        assert both.mean() > 0.9
        return float(np.median(np.abs(a[both] - b[both]) / a[both]))

    rc = depth(raycast=True)
    same = rel(rc, depth())  # measured 0.0036: the splat's nearest-wins bias (0.0036 unrotated too)
    unrotated = rel(depth(raycast=True, rotation_deg=[0, 0, 0]), depth(rotation_deg=[0, 0, 0]))
    assert same <= 1.05 * unrotated
    assert rel(rc, depth(rotation_deg=[0, 0, 0])) > 2 * same  # measured 0.0081
    assert rel(rc, depth(rotation_deg=[-a for a in LIRIS_DEG])) > 3 * same  # the other way round: 0.0138
