"""7-Scenes loader on a tiny folder written here in the original layout (no real 7-Scenes data is
available offline): random colour images, depth in millimetres with the invalid codes 0 and 65535,
and 4x4 camera-to-world pose files."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from gsslam.datasets import DatasetError, open_dataset
from gsslam.datasets.sevenscenes import SevenScenesDataset
from helpers.sevenscenes import write_sequence


def test_layout_depth_and_poses(tmp_path):
    truth = write_sequence(tmp_path / "chess" / "seq-01")
    ds = open_dataset("7scenes", tmp_path / "chess", sequence=1)
    assert len(ds) == 3 and ds.has_depth and ds.name == "chess_seq-01"
    K = ds.intrinsics
    assert (K.fx, K.fy, K.cx, K.cy, K.width, K.height, K.distortion) == (585, 585, 320, 240, 640, 480, ())
    np.testing.assert_allclose(ds.timestamps(), [0, 1 / 30, 2 / 30])
    f = ds[1]
    np.testing.assert_allclose(f.image, truth["color"][1], atol=1e-6)
    mm = truth["depth_mm"][1]
    assert np.isnan(f.depth[:10]).all() and np.isnan(f.depth[-10:]).all()
    np.testing.assert_allclose(f.depth[10:-10], mm[10:-10] / 1000.0, rtol=1e-6)
    np.testing.assert_allclose(f.T_world_cam_gt, truth["pose"][1], rtol=1e-8, atol=1e-9)
    gt = ds.ground_truth()
    np.testing.assert_allclose(gt.poses, np.stack(truth["pose"]), rtol=1e-8, atol=1e-9)
    assert gt.meta["frame_indices"] == [0, 1, 2]
    assert ds.ground_truth_camera == "depth"  # pose.txt: KinectFusion's poses of the depth camera


def test_missing_or_invalid_poses(tmp_path):
    seq = tmp_path / "seq-02"
    write_sequence(seq)
    (seq / "frame-000001.pose.txt").write_text("inf inf inf inf\n" * 4)
    (seq / "frame-000002.pose.txt").unlink()
    ds = SevenScenesDataset(seq)
    assert ds[1].T_world_cam_gt is None and ds[2].T_world_cam_gt is None
    assert ds.ground_truth().meta["frame_indices"] == [0]
    (seq / "frame-000000.pose.txt").write_text("1 0 0\n0 1 0\n")
    # a malformed pose file is refused when the dataset is opened, naming the file and the fix
    with pytest.raises(DatasetError, match=r"frame-000000\.pose\.txt: expected a 4x4.*delete it"):
        SevenScenesDataset(seq)


def test_malformed(tmp_path):
    seq = tmp_path / "seq-03"
    write_sequence(seq)
    good = (seq / "frame-000000.depth.png").read_bytes()
    cv2.imwrite(str(seq / "frame-000000.depth.png"), np.ones((240, 320), np.uint16))
    with pytest.raises(DatasetError, match=r"frame-000000\.depth\.png is 320x240 but .* 640x480"):
        SevenScenesDataset(seq)  # sizes are checked from the headers when the dataset is opened
    cv2.imwrite(str(seq / "frame-000000.depth.png"), np.ones((480, 640), np.uint8))
    with pytest.raises(DatasetError, match="8-bit.*16-bit"):
        SevenScenesDataset(seq)
    (seq / "frame-000000.depth.png").write_bytes(good)
    ds = SevenScenesDataset(seq)
    color = (seq / "frame-000001.color.png").read_bytes()
    (seq / "frame-000001.color.png").write_bytes(b"broken")
    with pytest.raises(DatasetError, match="corrupt"):
        ds[1]  # broken after opening: refused when read
    with pytest.raises(DatasetError, match=r"frame-000001\.color\.png \(corrupt"):
        SevenScenesDataset(seq)  # broken before opening: refused from its header
    (seq / "frame-000001.color.png").write_bytes(color)
    (seq / "frame-000002.depth.png").unlink()
    with pytest.raises(DatasetError, match="with_depth=False"):
        SevenScenesDataset(seq)
    assert SevenScenesDataset(seq, with_depth=False)[2].depth is None
    (tmp_path / "empty").mkdir()
    with pytest.raises(DatasetError, match="empty"):
        SevenScenesDataset(tmp_path / "empty")
    with pytest.raises(DatasetError, match="does not exist"):
        SevenScenesDataset(tmp_path, sequence="seq-09")
