"""KITTI odometry loader on the shared sequences 06 and 01, and on broken copies."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from gsslam.datasets import DatasetError, open_dataset
from gsslam.datasets.kitti import KittiOdometryDataset


@pytest.fixture(scope="module")
def kitti(shared_data) -> Path:
    return shared_data / "kitti_odometry"


def kitti_copy(src: Path, dst: Path, seq: str = "06", n: int = 3) -> Path:
    s, d = src / "sequences" / seq, dst / "sequences" / seq
    (d / "image_0").mkdir(parents=True)
    for i in range(n):
        shutil.copy(s / "image_0" / f"{i:06d}.png", d / "image_0" / f"{i:06d}.png")
    shutil.copy(s / "calib_P0_P1.txt", d / "calib_P0_P1.txt")
    (dst / "poses").mkdir()
    shutil.copy(src / "poses" / f"{seq}.txt", dst / "poses" / f"{seq}.txt")
    return dst


def test_seq06_from_root(kitti):
    ds = open_dataset("kitti", kitti, sequence="06")
    assert len(ds) == 51 and not ds.has_depth
    K = ds.intrinsics
    assert (K.fx, K.fy, K.cx, K.cy, K.width, K.height) == (707.0912, 707.0912, 601.8873, 183.1104, 1226, 370)
    times = np.loadtxt(kitti / "sequences" / "06" / "times.txt")
    np.testing.assert_array_equal(ds.timestamps(), times[:51])
    poses = np.loadtxt(kitti / "poses" / "06.txt").reshape(-1, 3, 4)
    assert len(ds.ground_truth()) == len(poses) == 1101
    np.testing.assert_allclose(ds[0].T_world_cam_gt, np.eye(4), atol=1e-9)
    np.testing.assert_allclose(ds[50].T_world_cam_gt[:3], poses[50], atol=1e-12)
    f = ds[50]
    raw = cv2.imread(str(kitti / "sequences" / "06" / "image_0" / "000050.png"), cv2.IMREAD_GRAYSCALE)
    np.testing.assert_allclose(f.image[..., 1], raw / 255.0, atol=1e-6)
    # the car drives forward (+z of the first camera) about 60 m in these 51 frames
    assert 55 < f.T_world_cam_gt[2, 3] < 65


def test_seq01_from_sequence_folder_without_times(kitti):
    ds = KittiOdometryDataset(kitti / "sequences" / "01")
    assert ds.sequence == "01" and len(ds) == 51
    assert ds.intrinsics.fx == 718.856 and (ds.intrinsics.width, ds.intrinsics.height) == (1241, 376)
    np.testing.assert_allclose(ds.timestamps(), np.arange(51) * 0.1)
    np.testing.assert_allclose(ds[0].T_world_cam_gt, np.eye(4), atol=1e-9)
    assert KittiOdometryDataset(kitti, sequence=1).name == "kitti_01"


def test_labelled_calib_and_right_camera(kitti, tmp_path):
    root = kitti_copy(kitti, tmp_path / "k")
    seq = root / "sequences" / "06"
    p0, p1 = (seq / "calib_P0_P1.txt").read_text().split("\n")[:2]
    (seq / "calib_P0_P1.txt").unlink()
    (seq / "calib.txt").write_text(f"P0: {p0}\nP1: {p1}\nTr: {' '.join(['0'] * 12)}\n")
    shutil.copytree(seq / "image_0", seq / "image_1")  # stand-in images: only the geometry is tested
    left = KittiOdometryDataset(root, sequence="06")
    right = KittiOdometryDataset(root, sequence="06", camera=1)
    assert left.intrinsics == right.intrinsics
    np.testing.assert_allclose(right.T_cam0_cam[:3, 3], [0.537150, 0, 0], atol=1e-5)  # stereo baseline
    np.testing.assert_allclose(right[0].T_world_cam_gt, np.eye(4), atol=1e-9)
    # both rigs move identically: right = inv(T_0_1) @ left @ T_0_1
    T01 = right.T_cam0_cam
    np.testing.assert_allclose(
        right[2].T_world_cam_gt, np.linalg.inv(T01) @ left[2].T_world_cam_gt @ T01, atol=1e-9
    )


def test_broken_copies(kitti, tmp_path):
    root = kitti_copy(kitti, tmp_path / "k")
    seq = root / "sequences" / "06"
    (seq / "times.txt").write_text("0.0\n0.1\n")
    with pytest.raises(DatasetError, match="times.txt has 2 rows"):
        KittiOdometryDataset(root, sequence="06")
    (seq / "times.txt").write_text("0.0\n0.2\n0.1\n")
    with pytest.raises(DatasetError, match="out-of-order"):
        KittiOdometryDataset(root, sequence="06")
    (seq / "times.txt").unlink()
    lines = (root / "poses" / "06.txt").read_text().splitlines()
    (root / "poses" / "06.txt").write_text("\n".join([lines[0], " ".join(lines[1].split()[:11])]) + "\n")
    with pytest.raises(DatasetError, match="12 numbers"):
        KittiOdometryDataset(root, sequence="06")
    (root / "poses" / "06.txt").unlink()
    ds = KittiOdometryDataset(root, sequence="06")  # no poses: no ground truth, not an error
    assert ds.ground_truth() is None and ds[1].T_world_cam_gt is None
    cv2.imwrite(str(seq / "image_0" / "000002.png"), np.zeros((10, 20), np.uint8))
    with pytest.raises(DatasetError, match="must match"):
        ds[2]
    (seq / "calib_P0_P1.txt").unlink()
    with pytest.raises(DatasetError, match="calib"):
        KittiOdometryDataset(root, sequence="06")
    with pytest.raises(DatasetError, match="sequence='XX'"):
        KittiOdometryDataset(root)
    with pytest.raises(DatasetError, match="empty"):
        KittiOdometryDataset(root, sequence="06", camera=2)
