"""EuRoC loader on the shared V1_01_easy prefix (+ its ground truth), and on broken copies."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from gsslam.datasets import DatasetError, open_dataset
from gsslam.datasets.euroc import EurocDataset, ns_to_s

T_BS_CAM0 = np.array(
    [
        [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975],
        [0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768],
        [-0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949],
        [0.0, 0.0, 0.0, 1.0],
    ]
)


@pytest.fixture(scope="module")
def euroc(shared_data) -> Path:
    return shared_data / "euroc_V1_01_easy"


@pytest.fixture(scope="module")
def gt_csv(shared_data) -> Path:
    return shared_data / "euroc_V1_01_easy_groundtruth" / "V1_01_easy.csv"


def euroc_copy(src: Path, dst: Path, n: int = 3) -> Path:
    cam = dst / "mav0" / "cam0"
    (cam / "data").mkdir(parents=True)
    shutil.copy(src / "mav0" / "cam0" / "sensor.yaml", cam / "sensor.yaml")
    lines = (src / "mav0" / "cam0" / "data.csv").read_text().splitlines()
    (cam / "data.csv").write_text("\n".join(lines[: n + 1]) + "\n")
    for line in lines[1 : n + 1]:
        name = line.split(",")[1].strip()
        shutil.copy(src / "mav0" / "cam0" / "data" / name, cam / "data" / name)
    return dst


def test_frames_timestamps_and_intrinsics(euroc):
    ds = open_dataset("euroc", euroc)
    assert len(ds) == 95 and not ds.has_depth
    K = ds.intrinsics
    assert (K.fx, K.fy, K.cx, K.cy, K.width, K.height) == (458.654, 457.296, 367.215, 248.375, 752, 480)
    assert K.distortion == ()
    np.testing.assert_allclose(ds.T_body_cam, T_BS_CAM0, atol=0)
    text = (euroc / "mav0" / "cam0" / "data.csv").read_text().splitlines()
    rows = np.array([l.split(",") for l in text if l and not l.startswith("#")])
    t_ns = np.array([int(x) for x in rows[:, 0]], dtype=np.int64)
    assert np.array_equal(ds.timestamps_ns(), t_ns)  # exact nanoseconds
    t = np.array(ds.timestamps())
    assert np.all(np.diff(t) > 0)
    np.testing.assert_allclose((t - 1403715273) * 1e9, (t_ns - 1403715273 * 10**9).astype(float), atol=500)
    f = ds[3]
    assert f.image.shape == (480, 752, 3) and f.depth is None
    assert np.array_equal(f.image[..., 0], f.image[..., 1]) and np.array_equal(
        f.image[..., 1], f.image[..., 2]
    )
    raw = cv2.imread(str(euroc / "mav0" / "cam0" / "data" / rows[3, 1].strip()), cv2.IMREAD_GRAYSCALE) / 255.0
    assert np.abs(f.image[..., 0] - raw).mean() > 0.01  # undistorted, not the raw image


def test_cam0_pose_is_body_pose_times_T_BS(euroc, gt_csv):
    ds = EurocDataset(euroc, gt_path=gt_csv)
    gt = np.loadtxt(gt_csv, delimiter=",", comments="#")
    t_ns = np.loadtxt(gt_csv, delimiter=",", comments="#", usecols=0, dtype=np.int64)
    assert len(ds.ground_truth()) == len(gt)
    for i in (0, 50, 94):
        f = ds[i]
        k = int(np.argmin(np.abs(t_ns - ds.timestamps_ns()[i])))
        T_W_B = np.eye(4)
        T_W_B[:3, :3] = Rotation.from_quat(gt[k, [5, 6, 7, 4]]).as_matrix()  # csv is qw qx qy qz
        T_W_B[:3, 3] = gt[k, 1:4]
        np.testing.assert_allclose(f.T_world_cam_gt, T_W_B @ T_BS_CAM0, atol=1e-9)
        assert f.timestamp == pytest.approx(ns_to_s(t_ns[k : k + 1])[0], abs=1e-6)
    assert len(ds.ground_truth_at_frames()) == 95


def test_gt_formats_and_discovery(euroc, gt_csv):
    auto = EurocDataset(euroc)  # sibling euroc_V1_01_easy_groundtruth/ holds one csv
    assert auto.ground_truth() is not None
    assert auto.ground_truth().meta["source"].endswith("V1_01_easy.csv")
    tum = EurocDataset(euroc, gt_path=gt_csv.with_suffix(".txt"))
    csv = EurocDataset(euroc, gt_path=gt_csv)
    np.testing.assert_allclose(tum.ground_truth().poses, csv.ground_truth().poses, atol=1e-5)
    # the original ASL GT starts 1.04 s after the first image: early frames get no pose
    orig = EurocDataset(euroc, gt_path=gt_csv.parent / "V1_01_easy_original.txt")
    assert orig[0].T_world_cam_gt is None and orig[94].T_world_cam_gt is not None


def test_imu_samples(euroc):
    imu = EurocDataset(euroc).imu()
    raw = np.loadtxt(euroc / "mav0" / "imu0" / "data.csv", delimiter=",", comments="#")
    assert len(imu) == len(raw) == 961
    np.testing.assert_array_equal(imu.gyro, raw[:, 1:4])
    np.testing.assert_array_equal(imu.accel, raw[:, 4:7])
    assert imu.timestamps_ns[0] == 1403715273262142976 and np.all(np.diff(imu.timestamps) > 0)
    assert imu.noise["gyroscope_noise_density"] == pytest.approx(1.6968e-04)
    assert 9.0 < np.linalg.norm(imu.accel, axis=1).mean() < 10.6  # gravity while nearly still


def test_broken_copies(euroc, tmp_path):
    path = euroc_copy(euroc, tmp_path / "seq")
    ds = EurocDataset(path / "mav0")  # the mav0 folder itself is accepted
    assert len(ds) == 3 and ds.ground_truth() is None and ds[2].T_world_cam_gt is None
    with pytest.raises(DatasetError, match="imu0"):
        ds.imu()
    name = sorted((path / "mav0" / "cam0" / "data").iterdir())[0]
    name.write_bytes(b"not a png")
    with pytest.raises(DatasetError, match="corrupt"):
        ds[0]
    csv = path / "mav0" / "cam0" / "data.csv"
    lines = csv.read_text().splitlines()
    csv.write_text("\n".join([lines[0], lines[2], lines[1], lines[3]]) + "\n")
    with pytest.raises(DatasetError, match="out-of-order"):
        EurocDataset(path)
    csv.write_text(lines[0] + "\n")
    with pytest.raises(DatasetError, match="empty"):
        EurocDataset(path)
    with pytest.raises(DatasetError, match="ground-truth file is missing"):
        EurocDataset(euroc, gt_path=tmp_path / "nope.csv")
    (path / "mav0" / "cam0" / "sensor.yaml").unlink()
    with pytest.raises(DatasetError, match="sensor.yaml"):
        EurocDataset(path)
    with pytest.raises(DatasetError, match="mav0"):
        EurocDataset(tmp_path)


def test_bundled_prefix(repo_root):
    """data/euroc_V1_01_easy_20 loads without ../shared: 20 undistorted frames and their IMU window."""
    ds = open_dataset("euroc", repo_root / "data" / "euroc_V1_01_easy_20")
    assert len(ds) == 20 and ds.ground_truth() is None and ds[19].T_world_cam_gt is None
    np.testing.assert_allclose(ds.T_body_cam, T_BS_CAM0, atol=0)
    imu = ds.imu()
    t = ds.timestamps_ns()
    assert len(imu) == 211 and imu.timestamps_ns[0] == t[0]
    assert imu.timestamps_ns[-1] == t[-1] + 100_000_000  # every sample up to the last image + 0.1 s
    f = ds[19]
    assert f.image.shape == (480, 752, 3) and f.intrinsics.distortion == ()
