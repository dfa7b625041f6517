"""TUM RGB-D loader on the bundled and shared fr3/teddy data, and on broken copies of it."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from gsslam.datasets import DatasetError, open_dataset
from gsslam.datasets.tum import TUM_INTRINSICS, TumRgbdDataset
from gsslam.types import CameraIntrinsics
from helpers.tum import copy_tum_prefix, list_entries


def test_bundled_frames_depth_and_intrinsics(bundled_tum):
    ds = open_dataset("tum", bundled_tum)
    assert len(ds) == 60 and ds.has_depth
    assert ds.intrinsics == TUM_INTRINSICS[3] and ds.intrinsics.distortion == ()
    f = ds[7]
    assert f.index == 7 and f.image.shape == (480, 640, 3) and f.image.dtype == np.float32
    assert 0.0 <= f.image.min() and f.image.max() <= 1.0
    _, rgb_rows = list_entries(bundled_tum / "rgb.txt")
    t, rel = rgb_rows[7].split()
    assert f.timestamp == float(t)
    bgr = cv2.imread(str(bundled_tum / rel))
    np.testing.assert_allclose(f.image, bgr[:, :, ::-1] / 255.0, atol=1e-6)
    # depth: nearest depth.txt entry, value / 5000, 0 -> NaN
    _, depth_rows = list_entries(bundled_tum / "depth.txt")
    d_t = np.array([float(r.split()[0]) for r in depth_rows])
    j = int(np.argmin(np.abs(d_t - float(t))))
    raw = cv2.imread(str(bundled_tum / depth_rows[j].split()[1]), cv2.IMREAD_UNCHANGED)
    assert np.array_equal(np.isnan(f.depth), raw == 0)
    np.testing.assert_allclose(f.depth[raw > 0], raw[raw > 0] / 5000.0, rtol=1e-6)


def test_bundled_ground_truth_equals_file_rows(bundled_tum):
    ds = TumRgbdDataset(bundled_tum)
    gt_rows = np.loadtxt(bundled_tum / "groundtruth.txt")
    gt = ds.ground_truth()
    assert len(gt) == len(gt_rows)
    np.testing.assert_array_equal(gt.timestamps, gt_rows[:, 0])
    # the first frames come before the first GT pose: no crash, no pose
    assert ds[0].T_world_cam_gt is None
    for i in (10, 59):
        f = ds[i]
        row = gt_rows[np.argmin(np.abs(gt_rows[:, 0] - f.timestamp))]
        expected = np.eye(4)
        expected[:3, :3] = Rotation.from_quat(row[4:8]).as_matrix()  # scipy order is (x, y, z, w)
        expected[:3, 3] = row[1:4]
        np.testing.assert_allclose(f.T_world_cam_gt, expected, atol=1e-9)
    at = ds.ground_truth_at_frames()
    idx = at.meta["frame_indices"]
    frame_t = np.array(ds.timestamps())
    assert all(frame_t[i] >= gt_rows[0, 0] - ds.max_dt for i in idx)
    assert all(ds[i].T_world_cam_gt is None for i in range(len(ds)) if i not in idx)
    np.testing.assert_array_equal(at.timestamps, frame_t[idx])


def test_shared_teddy_200_frames_and_depth_policy(shared_data):
    path = shared_data / "rgbd_dataset_freiburg3_teddy"
    every = TumRgbdDataset(path, missing_depth="none")
    assert len(every) == 200
    no_depth = [i for i in range(len(every)) if every._depth[i] is None]
    assert no_depth  # this stretch of teddy really has rgb frames without depth within 0.02 s
    assert every[no_depth[0]].depth is None
    skipped = TumRgbdDataset(path)  # default "skip": every frame has depth
    assert len(skipped) == 200 - len(no_depth)
    assert skipped[len(skipped) - 1].depth is not None
    assert len(skipped.ground_truth()) == 8080
    with pytest.raises(DatasetError, match="no depth within"):
        TumRgbdDataset(path, missing_depth="error")
    assert TumRgbdDataset(path, max_dt=0.05, missing_depth="error")[0].depth is not None


def test_fr1_folder_name_undistorts(bundled_tum, tmp_path):
    raw = TumRgbdDataset(bundled_tum)
    ds = TumRgbdDataset(copy_tum_prefix(bundled_tum, tmp_path / "rgbd_dataset_freiburg1_copy", 2))
    assert ds.intrinsics.K.tolist() == TUM_INTRINSICS[1].K.tolist() and ds.intrinsics.distortion == ()
    a, b = raw[0], ds[0]
    assert np.abs(a.image - b.image).mean() > 0.01  # the fr1 distortion model moved pixels
    # near the principal point the distortion is tiny: the image barely changes there
    cy, cx = int(round(ds.intrinsics.cy)), int(round(ds.intrinsics.cx))
    assert (
        np.abs(a.image[cy - 3 : cy + 4, cx - 3 : cx + 4] - b.image[cy - 3 : cy + 4, cx - 3 : cx + 4]).mean()
        < 0.02
    )
    assert np.isnan(b.depth[0, 0]) and np.isnan(b.depth).mean() > np.isnan(a.depth).mean()
    valid = ~np.isnan(b.depth)
    assert np.isin(b.depth[valid], a.depth[~np.isnan(a.depth)]).all()  # nearest: no new depth values


def test_intrinsics_from_kwarg_or_file_when_name_is_unknown(bundled_tum, tmp_path):
    path = copy_tum_prefix(bundled_tum, tmp_path / "my_sequence", 2)
    with pytest.raises(DatasetError, match="freiburg"):
        TumRgbdDataset(path)
    K = CameraIntrinsics(500.0, 500.0, 320.0, 240.0, 640, 480)
    assert TumRgbdDataset(path, intrinsics=K)[1].intrinsics == K
    (tmp_path / "k.yaml").write_text("fx: 500\nfy: 500\ncx: 320\ncy: 240\n")
    assert TumRgbdDataset(path, intrinsics_file=tmp_path / "k.yaml").intrinsics == K


def test_rgb_only(bundled_tum):
    ds = TumRgbdDataset(bundled_tum, with_depth=False)
    assert not ds.has_depth and ds[0].depth is None and len(ds) == 60


def _break(path: Path, lst: str, fn) -> None:
    head, rows = list_entries(path / lst)
    (path / lst).write_text("\n".join(head + fn(rows)) + "\n")


@pytest.mark.parametrize(
    "fn, match",
    [
        (lambda r: [r[1], r[0]] + r[2:], "out-of-order"),
        (lambda r: r[:2] + [r[1]] + r[2:], "duplicate"),
        (lambda r: [], "empty"),
        (lambda r: [r[0].split()[0]] + r[1:], "timestamp filename"),
    ],
)
def test_malformed_rgb_list(bundled_tum, tmp_path, fn, match):
    path = copy_tum_prefix(bundled_tum, tmp_path / "rgbd_dataset_freiburg3_bad", 4)
    _break(path, "rgb.txt", fn)
    with pytest.raises(DatasetError, match=match):
        TumRgbdDataset(path)


def test_missing_files_and_corrupt_images(bundled_tum, tmp_path):
    path = copy_tum_prefix(bundled_tum, tmp_path / "rgbd_dataset_freiburg3_bad", 4)
    ds = TumRgbdDataset(path)
    _, rows = list_entries(path / "rgb.txt")
    (path / rows[0].split()[1]).write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    with pytest.raises(DatasetError, match="corrupt"):
        ds[0]
    (path / rows[1].split()[1]).unlink()
    with pytest.raises(DatasetError, match="missing"):
        ds[1]
    _, drows = list_entries(path / "depth.txt")
    small = np.full((240, 320), 5000, np.uint16)
    cv2.imwrite(str(path / drows[2].split()[1]), small)
    with pytest.raises(DatasetError, match="registered"):
        ds[2]
    with pytest.raises(IndexError):
        ds[4]
    assert ds[-1].index == 3
    (path / "depth.txt").unlink()
    with pytest.raises(DatasetError, match="depth.txt"):
        TumRgbdDataset(path)
    with pytest.raises(DatasetError, match="does not exist"):
        TumRgbdDataset(tmp_path / "nowhere_freiburg3")


def test_unsorted_groundtruth(bundled_tum, tmp_path):
    path = copy_tum_prefix(bundled_tum, tmp_path / "rgbd_dataset_freiburg3_bad", 2)
    _break(path, "groundtruth.txt", lambda r: [r[3]] + r)
    with pytest.raises(DatasetError, match="groundtruth.txt"):
        TumRgbdDataset(path)
