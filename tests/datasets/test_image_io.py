"""Image decoding, depth conversion and undistortion shared by the loaders."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from gsslam.datasets import DatasetError
from gsslam.datasets.common import associate_nearest, check_increasing
from gsslam.datasets.image_io import Undistorter, read_color, read_depth
from gsslam.types import CameraIntrinsics

FR1 = CameraIntrinsics(517.3, 516.5, 318.6, 255.3, 640, 480, (0.2624, -0.9531, -0.0054, 0.0026, 1.1633))
EUROC = CameraIntrinsics(
    458.654, 457.296, 367.215, 248.375, 752, 480, (-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05)
)


def _pattern(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """A smooth test scene on the ideal (pinhole) image plane."""
    return 0.5 + 0.25 * np.sin(2 * np.pi * u / 23.0) + 0.25 * np.cos(2 * np.pi * v / 17.0)


@pytest.mark.parametrize("cam", [FR1, EUROC])
def test_undistortion_recovers_the_pinhole_image(cam):
    """Render what the *distorted* camera sees of a scene painted on the pinhole image plane
    (each distorted pixel looks up its ideal position with cv2.undistortPoints); undistorting
    must give back the pinhole image of that scene."""
    h, w = cam.height, cam.width
    grid = np.stack(np.meshgrid(np.arange(w), np.arange(h)), -1).reshape(-1, 1, 2).astype(np.float64)
    ideal = cv2.undistortPoints(grid, cam.K, np.array(cam.distortion), P=cam.K).reshape(h, w, 2)
    distorted = _pattern(ideal[..., 0], ideal[..., 1]).astype(np.float32)
    img = np.repeat(distorted[:, :, None], 3, axis=2)
    und = Undistorter(cam)
    assert und.intrinsics_out.distortion == () and np.array_equal(und.intrinsics_out.K, cam.K)
    out = und.image(img)[..., 0]
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    expected = _pattern(u, v)
    central = (np.abs(u - cam.cx) < 0.35 * w) & (np.abs(v - cam.cy) < 0.35 * h)
    err = np.abs(out - expected)[central]
    assert np.abs(distorted - expected)[central].mean() > 0.1  # the lens really moves the scene
    assert err.mean() < 0.01 and np.percentile(err, 99) < 0.05


def test_no_distortion_is_identity_and_size_is_checked():
    cam = CameraIntrinsics(500, 500, 320, 240, 640, 480)
    und = Undistorter(cam)
    img = np.random.default_rng(0).random((480, 640, 3), dtype=np.float32)
    assert und.image(img) is img
    with pytest.raises(DatasetError, match="640x480"):
        und.image(img[:240])


def test_read_color_and_depth(tmp_path):
    gray16 = np.arange(12, dtype=np.uint16).reshape(3, 4) * 5000
    cv2.imwrite(str(tmp_path / "g16.png"), gray16)
    c = read_color(tmp_path / "g16.png")
    assert c.shape == (3, 4, 3) and c.dtype == np.float32
    np.testing.assert_allclose(c[..., 2], gray16 / 65535.0, rtol=1e-6)
    d = read_depth(tmp_path / "g16.png", 5000.0)
    assert np.isnan(d[0, 0]) and np.isnan(d).sum() == 1
    np.testing.assert_allclose(d.reshape(-1)[1:], np.arange(1, 12), rtol=1e-6)
    bgr = np.zeros((2, 2, 3), np.uint8)
    bgr[..., 0] = 255  # blue in OpenCV order
    cv2.imwrite(str(tmp_path / "b.png"), bgr)
    np.testing.assert_array_equal(read_color(tmp_path / "b.png")[0, 0], [0, 0, 1])
    with pytest.raises(DatasetError, match="single-channel"):
        read_depth(tmp_path / "b.png", 1000.0)


def test_associate_nearest_matches_brute_force():
    rng = np.random.default_rng(3)
    ref = np.sort(rng.uniform(0, 10, 200))
    query = rng.uniform(-1, 11, 500)
    got = associate_nearest(query, ref, 0.02)
    for q, g in zip(query, got):
        k = int(np.argmin(np.abs(ref - q)))
        assert g == (k if abs(ref[k] - q) <= 0.02 else -1)
    assert associate_nearest(query, ref[:1], 100.0).tolist() == [0] * len(query)
    assert (associate_nearest(query, np.array([]), 1.0) == -1).all()


def test_check_increasing():
    check_increasing(np.array([1.0, 2.0, 3.0]), "x")
    with pytest.raises(DatasetError, match="duplicate"):
        check_increasing(np.array([1.0, 2.0, 2.0]), "x")
    with pytest.raises(DatasetError, match=r"line 7"):
        check_increasing(np.array([1.0, 3.0, 2.0]), "x", [5, 6, 7])


def test_headers_are_checked_without_decoding(tmp_path):
    from gsslam.datasets.image_io import check_image_files

    for name, arr in (
        ("a.png", np.zeros((6, 8, 3), np.uint8)),
        ("b.png", np.zeros((6, 8, 3), np.uint8)),
        ("d16.png", np.ones((6, 8), np.uint16)),
        ("d8.png", np.ones((6, 8), np.uint8)),
        ("odd.png", np.zeros((4, 8, 3), np.uint8)),
    ):
        cv2.imwrite(str(tmp_path / name), arr)
    assert check_image_files([tmp_path / "a.png", tmp_path / "b.png"], None, "image") == (8, 6)
    assert check_image_files([tmp_path / "d16.png"], (8, 6), "depth map", depth=True) == (8, 6)
    with pytest.raises(DatasetError, match=r"odd\.png is 8x4 but a\.png is 8x6"):
        check_image_files([tmp_path / "a.png", tmp_path / "odd.png"], None, "image")
    with pytest.raises(DatasetError, match=r"odd\.png is 8x4 but the camera calibration is for 8x6"):
        check_image_files([tmp_path / "odd.png"], (8, 6), "image")
    with pytest.raises(DatasetError, match=r"d8\.png is 8-bit; depth must be a single-channel 16-bit"):
        check_image_files([tmp_path / "d8.png"], (8, 6), "depth map", depth=True)
    with pytest.raises(DatasetError, match="8-bit"):
        read_depth(tmp_path / "d8.png", 1000.0)
    with pytest.raises(DatasetError, match="missing"):
        check_image_files([tmp_path / "nope.png"], None, "image")
