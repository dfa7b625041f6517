"""Image-folder and video loader on frames of the bundled TUM sequence."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from gsslam.datasets import DatasetError, open_dataset
from gsslam.datasets.images import ImageSequenceDataset

YAML = "fx: 535.4\nfy: 539.2\ncx: 320.1\ncy: 247.6\nfps: 15\n"


def image_folder(bundled_tum: Path, dst: Path, n: int = 4) -> list[Path]:
    dst.mkdir()
    src = sorted((bundled_tum / "rgb").glob("*.png"))[:n]
    for i, p in enumerate(src):
        shutil.copy(p, dst / f"img_{i:03d}.png")
    return src


def test_folder_with_yaml_intrinsics(bundled_tum, tmp_path):
    src = image_folder(bundled_tum, tmp_path / "imgs")
    (tmp_path / "k.yaml").write_text(YAML)
    ds = open_dataset("images", tmp_path / "imgs", intrinsics_file=tmp_path / "k.yaml")
    assert len(ds) == 4 and not ds.has_depth and ds.ground_truth() is None
    assert (ds.intrinsics.fx, ds.intrinsics.width, ds.intrinsics.height) == (535.4, 640, 480)
    np.testing.assert_allclose(ds.timestamps(), np.arange(4) / 15)
    f = ds[2]
    np.testing.assert_allclose(f.image, cv2.imread(str(src[2]))[:, :, ::-1] / 255.0, atol=1e-6)
    assert f.timestamp == pytest.approx(2 / 15)


def test_distortion_in_yaml_is_removed(bundled_tum, tmp_path):
    image_folder(bundled_tum, tmp_path / "imgs", n=1)
    (tmp_path / "k.yaml").write_text(YAML + "distortion: [0.2624, -0.9531, -0.0054, 0.0026, 1.1633]\n")
    plain = ImageSequenceDataset(tmp_path / "imgs", fx=535.4, fy=539.2, cx=320.1, cy=247.6)
    ds = ImageSequenceDataset(tmp_path / "imgs", intrinsics_file=tmp_path / "k.yaml")
    assert ds.intrinsics.distortion == () and ds.intrinsics.K.tolist() == plain.intrinsics.K.tolist()
    assert np.abs(ds[0].image - plain[0].image).mean() > 0.01
    assert plain.fps == 30.0


def test_video_random_access(bundled_tum, tmp_path):
    src = sorted((bundled_tum / "rgb").glob("*.png"))[:6]
    video = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 12.0, (640, 480))
    if not writer.isOpened():
        pytest.skip("this OpenCV build cannot write MJPG video")
    frames = [cv2.imread(str(p)) for p in src]
    for img in frames:
        writer.write(img)
    writer.release()
    ds = ImageSequenceDataset(video, fx=535.4, fy=539.2, cx=320.1, cy=247.6)
    assert len(ds) == 6 and ds.fps == pytest.approx(12.0)
    seq = [ds[i].image for i in range(6)]
    for i in (4, 1, 5, 0):  # jumps back and forth give the same frames as reading in order
        np.testing.assert_array_equal(ds[i].image, seq[i])
    for i, img in enumerate(frames):  # and they are the written frames, up to JPEG loss
        assert np.abs(seq[i] - img[:, :, ::-1] / 255.0).mean() < 0.03
    assert np.abs(seq[0] - seq[5]).mean() > np.abs(seq[0] - frames[0][:, :, ::-1] / 255.0).mean()


def test_malformed(bundled_tum, tmp_path):
    image_folder(bundled_tum, tmp_path / "imgs", n=2)
    with pytest.raises(DatasetError, match="intrinsics_file"):
        ImageSequenceDataset(tmp_path / "imgs")
    (tmp_path / "bad.yaml").write_text("fx: 500\nfy: 500\n")
    with pytest.raises(DatasetError, match="cx, cy"):
        ImageSequenceDataset(tmp_path / "imgs", intrinsics_file=tmp_path / "bad.yaml")
    (tmp_path / "size.yaml").write_text(YAML + "width: 320\nheight: 240\n")
    with pytest.raises(DatasetError, match="320x240"):
        ImageSequenceDataset(tmp_path / "imgs", intrinsics_file=tmp_path / "size.yaml")
    ds = ImageSequenceDataset(tmp_path / "imgs", fx=500, fy=500, cx=320, cy=240)
    (tmp_path / "imgs" / "img_001.png").write_bytes(b"\x89PNG broken")
    with pytest.raises(DatasetError, match="corrupt"):
        ds[1]
    cv2.imwrite(str(tmp_path / "imgs" / "img_001.png"), np.zeros((240, 320, 3), np.uint8))
    with pytest.raises(DatasetError, match="320x240"):
        ds[1]
    (tmp_path / "empty").mkdir()
    with pytest.raises(DatasetError, match="empty"):
        ImageSequenceDataset(tmp_path / "empty", fx=500, fy=500, cx=320, cy=240)
    (tmp_path / "not_a_video.mp4").write_bytes(b"nothing")
    with pytest.raises(DatasetError, match="video"):
        ImageSequenceDataset(tmp_path / "not_a_video.mp4", fx=500, fy=500, cx=320, cy=240)


ROS_CAMERA_INFO = """image_width: 640
image_height: 480
camera_name: rgb
camera_matrix:
  rows: 3
  cols: 3
  data: [535.4, 0, 320.1, 0, 539.2, 247.6, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [0.2624, -0.9531, -0.0054, 0.0026, 1.1633]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
"""


def test_ros_camera_info_yaml_is_accepted(bundled_tum, tmp_path):
    from gsslam.datasets.common import load_intrinsics_yaml

    image_folder(bundled_tum, tmp_path / "imgs", n=1)
    (tmp_path / "ros.yaml").write_text(ROS_CAMERA_INFO)
    (tmp_path / "k.yaml").write_text(YAML + "distortion: [0.2624, -0.9531, -0.0054, 0.0026, 1.1633]\n")
    ros = load_intrinsics_yaml(tmp_path / "ros.yaml")
    assert (ros.fx, ros.fy, ros.cx, ros.cy, ros.width, ros.height) == (535.4, 539.2, 320.1, 247.6, 640, 480)
    assert ros.distortion == (0.2624, -0.9531, -0.0054, 0.0026, 1.1633)
    a = ImageSequenceDataset(tmp_path / "imgs", intrinsics_file=tmp_path / "ros.yaml")
    b = ImageSequenceDataset(tmp_path / "imgs", intrinsics_file=tmp_path / "k.yaml")
    np.testing.assert_array_equal(a[0].image, b[0].image)  # undistorted the same way
    (tmp_path / "fish.yaml").write_text(ROS_CAMERA_INFO.replace("plumb_bob", "equidistant"))
    with pytest.raises(DatasetError, match="equidistant"):
        load_intrinsics_yaml(tmp_path / "fish.yaml")
