"""Frames fed from a user's own code: wrong units are refused with the fix, explicit conversion works.

The arrays are the bundled teddy frame 0 in the units a user's code might hand over by mistake."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from reliability_helpers import BUNDLED_TUM, list_files

from gsslam.datasets.tum import TumRgbdDataset
from gsslam.types import CameraIntrinsics, Frame, TypesError


@pytest.fixture(scope="module")
def raw():
    """(bgr uint8 [H, W, 3], depth uint16 [H, W] in TUM units (5000 / m), intrinsics)."""
    bgr = cv2.imread(str(list_files(BUNDLED_TUM, "rgb.txt")[0]), cv2.IMREAD_COLOR)
    depth = cv2.imread(str(list_files(BUNDLED_TUM, "depth.txt")[0]), cv2.IMREAD_UNCHANGED)
    return bgr[..., ::-1].copy(), depth, TumRgbdDataset(BUNDLED_TUM).intrinsics


def _metres(depth_raw: np.ndarray) -> np.ndarray:
    return np.where(depth_raw > 0, depth_raw / 5000.0, np.nan).astype(np.float32)


@pytest.mark.parametrize(
    "case, message",
    [
        ("uint8 image", r"image is uint8; colour must be float in \[0, 1\].*Frame\.from_arrays"),
        ("0..255 float image", r"image values span .*255.*divide by 255"),
        ("NaN in image", r"image holds NaN"),
        ("millimetre depth", r"median depth is .* can only be millimetres.*depth_scale"),
        ("raw uint16 depth", r"depth is uint16 \(raw sensor units\?\).*depth_scale=5000"),
        ("negative depth", r"inf or negative"),
        ("non-finite pose", r"T_world_cam_gt must be a finite"),
    ],
)
def test_wrong_units_are_refused(raw, case, message):
    rgb, depth_raw, K = raw
    image, depth, pose = rgb.astype(np.float32) / 255, _metres(depth_raw), np.eye(4)
    if case == "uint8 image":
        image = rgb
    elif case == "0..255 float image":
        image = rgb.astype(np.float32)
    elif case == "NaN in image":
        image = image.copy()
        image[3, 4, 1] = np.nan
    elif case == "millimetre depth":
        depth = depth * 1000
    elif case == "raw uint16 depth":
        depth = depth_raw
    elif case == "negative depth":
        depth = -depth
    elif case == "non-finite pose":
        pose = np.full((4, 4), np.nan)
    Frame(0, 0.0, rgb.astype(np.float32) / 255, K, _metres(depth_raw), np.eye(4))  # the right units pass
    with pytest.raises(TypesError, match=message):
        Frame(0, 0.0, image, K, depth, pose)


def test_explicit_conversion_from_sensor_units(raw):
    rgb, depth_raw, K = raw
    f = Frame.from_arrays(3, 0.1, rgb, K, depth_raw, depth_scale=5000.0)
    assert f.image.dtype == np.float32 and 0.0 <= f.image.min() and f.image.max() <= 1.0
    np.testing.assert_allclose(f.image, rgb / 255.0, atol=1e-6)
    np.testing.assert_array_equal(np.isnan(f.depth), depth_raw == 0)
    np.testing.assert_allclose(f.depth[depth_raw > 0], depth_raw[depth_raw > 0] / 5000.0, rtol=1e-6)
    ds = TumRgbdDataset(BUNDLED_TUM)[0]  # the loader's frame is the same
    np.testing.assert_allclose(f.depth, ds.depth, rtol=1e-6, equal_nan=True)
    mm = Frame.from_arrays(0, 0.0, rgb, K, (depth_raw // 5).astype(np.uint16), depth_scale=1000.0)
    assert abs(np.nanmedian(mm.depth) - np.nanmedian(ds.depth)) < 0.002
    with pytest.raises(TypesError, match="pass depth_scale="):
        Frame.from_arrays(0, 0.0, rgb, K, depth_raw)
    with pytest.raises(TypesError, match="image dtype int64"):
        Frame.from_arrays(0, 0.0, rgb.astype(np.int64), K)


def test_intrinsics_must_be_finite():
    with pytest.raises(TypesError, match="principal point"):
        CameraIntrinsics(500.0, 500.0, float("nan"), 240.0, 640, 480)
    with pytest.raises(TypesError, match="focal"):
        CameraIntrinsics(float("inf"), 500.0, 320.0, 240.0, 640, 480)
